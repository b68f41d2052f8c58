"""The study's samples rendered: simulated, reconstructed, scored and cached, serially or on
Dask (:mod:`~clnlos.study.samples.render`), the measured resolution the glyph templates are
blurred to (:mod:`~clnlos.study.samples.resolution`) and every reconstruction identified
(:mod:`~clnlos.study.samples.identify`)."""
