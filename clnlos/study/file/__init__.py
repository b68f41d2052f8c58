"""The study file (``clnlos study STUDY.toml``, ``clnlos.study("STUDY.toml" | dict)``): a
rig, materials, targets, sweeps and inversions, parsed and checked before any work
(:mod:`~clnlos.study.file.spec`); the quick and the full study are two such files shipped in
``clnlos/data`` (:func:`~clnlos.study.file.spec.builtin_study`)."""
