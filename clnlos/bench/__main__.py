"""``python -m clnlos.bench [--quick | --tiny] [-o DIR] [--only SECTIONS]``: the same as
``clnlos bench`` (:func:`clnlos.bench.main`)."""

from clnlos.bench import main

main()
