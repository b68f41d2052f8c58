"""Judgement without ground truth: the legibility judge (its features
:mod:`~clnlos.study.judge.features`, the logistic model :mod:`~clnlos.study.judge.model`,
its twins :mod:`~clnlos.study.judge.twins`, held-out metrics :mod:`~clnlos.study.judge.heldout`,
its check on the real thinning ladders :mod:`~clnlos.study.judge.real`, its training in a
study :mod:`~clnlos.study.judge.study`, ``clnlos legibility`` :mod:`~clnlos.study.judge.apply`)
and the seed recipe's torch CNN (:mod:`~clnlos.study.judge.cnn`)."""
