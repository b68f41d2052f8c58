"""Real captures in the study: a capture beside its simulated twin
(:mod:`~clnlos.study.real.capture`), nested binomial thinning, the exact model of a shorter
exposure (:mod:`~clnlos.study.real.thinning`), and the photons a real target needs per
inversion and reflectance (:mod:`~clnlos.study.real.materials`)."""
