"""The study's answer in tables, numbers and words: per material, sweep and tilt
(:mod:`~clnlos.study.findings.sweeps`), the findings (:mod:`~clnlos.study.findings.summary`)
and their sentences (:mod:`~clnlos.study.findings.text`), the materials under both
transports (:mod:`~clnlos.study.findings.transport`) and the confocal approximation's error
(:mod:`~clnlos.study.findings.confocal_error`)."""
