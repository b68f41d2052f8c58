"""The study's report.html: the page (:mod:`~clnlos.study.report.page`), its first screen
(:mod:`~clnlos.study.report.headline`), its figures (:mod:`~clnlos.study.report.figures`)
and the judge's and the CNN's section (:mod:`~clnlos.study.report.classifier`)."""
