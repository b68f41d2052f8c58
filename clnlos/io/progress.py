"""Progress bars of the long jobs (the one pattern every command follows).

A bar is tqdm on stderr that appears only once its job has run PROGRESS_DELAY_S seconds (short
runs print nothing) and is removed when the job ends (``leave=False``). Library functions take
a plain callback instead of a bar -- ``progress(done, total)`` -- so they stay usable (and
testable) without one; :func:`counter` turns a bar into such a callback and :func:`stage`
names the step that is running (set-up steps that have no count of their own).
"""

from __future__ import annotations

from tqdm import tqdm

PROGRESS_DELAY_S = 2.0  # a bar is shown once its job has run this long (s)


def progress_bar(total: int | None, desc: str, unit: str):
    """A tqdm bar on stderr for ``total`` ``unit``s (None: not known yet), shown after
    PROGRESS_DELAY_S and removed when closed; use it as a context manager."""
    return tqdm(total=total, desc=desc, unit=unit, delay=PROGRESS_DELAY_S, leave=False)


def counter(bar):
    """A ``progress(done, total)`` callback that moves ``bar`` to ``done`` of ``total`` (the
    total may be learnt, or change, on the way); a call with the same ``done`` only lets
    the bar appear once PROGRESS_DELAY_S has passed and its clock tick."""
    def progress(done, total) -> None:
        if total is not None and bar.total != total:
            bar.total = total
        if done != bar.n:
            bar.update(done - bar.n)
        else:
            _tick(bar)
    return progress


def stage(bar, text: str) -> None:
    """Show ``text`` (the step now running) beside ``bar`` without moving it (steps are
    few: each is drawn once PROGRESS_DELAY_S has passed)."""
    bar.set_postfix_str(text, refresh=False)
    _tick(bar, every_s=0.0)


def _tick(bar, every_s: float | None = None) -> None:
    """Redraw ``bar`` (its clock, its postfix) once PROGRESS_DELAY_S has passed, at most
    every ``every_s`` seconds (default: the bar's ``mininterval``, as tqdm does on an
    update)."""
    if bar.disable:
        return
    every_s = bar.mininterval if every_s is None else every_s
    now = bar.format_dict["elapsed"]
    if now >= PROGRESS_DELAY_S and now - (bar.last_print_t - bar.start_t) >= every_s:
        bar.refresh()
        bar.last_print_t = bar.start_t + now
