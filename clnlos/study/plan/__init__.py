"""What a study renders, from its options (pure: nothing is rendered here): the sample's
scene and the rig every sample shares (:mod:`~clnlos.study.plan.scenes`), the hidden
patterns (:mod:`~clnlos.study.score.patterns`) and every (meta, sample) of a study
(:mod:`~clnlos.study.plan.entries`)."""
