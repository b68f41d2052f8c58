"""How a reconstruction is scored (pure numpy / scipy, no OpenCL): the ground-truth masks and
IoU (:mod:`~clnlos.study.score.metrics`), legibility (identification among templates, the
filled-box baseline, Wilson intervals: :mod:`~clnlos.study.score.legibility`), the
no-reference quality metrics (:mod:`~clnlos.study.score.quality`) and the seed's FFT clarity
(:mod:`~clnlos.study.score.clarity`)."""
