"""Judgement without ground truth: the legibility judge (its features
:mod:`~clnlos.study.judge.features`, the logistic models :mod:`~clnlos.study.judge.model`, what
it knows and how sure it is :mod:`~clnlos.study.judge.domain`, how it reconstructs a capture
:mod:`~clnlos.study.judge.recipe`, its twins :mod:`~clnlos.study.judge.twins` and their
targets :mod:`~clnlos.study.judge.targets`, held-out metrics :mod:`~clnlos.study.judge.heldout`,
its check on the real thinning ladders :mod:`~clnlos.study.judge.real`, its training in a
study :mod:`~clnlos.study.judge.study`, ``clnlos legibility`` and the judge shipped with
clnlos :mod:`~clnlos.study.judge.apply`) and the seed recipe's torch CNN
(:mod:`~clnlos.study.judge.cnn`)."""
