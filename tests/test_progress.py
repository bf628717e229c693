"""The progress line of long sim-time runs."""

import io

from dockhil.progress import Progress


class Tty(io.StringIO):
    def isatty(self):
        return True


def test_progress_shows_simulated_time_share_and_real_time_factor_in_place():
    stream = Tty()
    bar = Progress(total_ticks=3001, dt=1e-3, stream=stream)
    bar.update(1501, force=True)
    text = stream.getvalue()
    assert text.startswith("\r[" + "#" * 12) and "1.50 of 3.00 s simulated" in text and "x real time" in text
    bar.update(3001, force=True)
    assert stream.getvalue().count("\r") == 2 and "\n" not in stream.getvalue()
    bar.done()
    assert stream.getvalue().endswith("\r\x1b[K")  # the line is erased, the summary follows cleanly


def test_progress_in_a_log_is_a_line_every_few_seconds():
    stream = io.StringIO()
    bar = Progress(total_ticks=None, dt=1e-3, stream=stream)
    bar.update(10)  # too soon after the start for a log line
    assert stream.getvalue() == ""
    bar.update(2001, force=True)
    assert stream.getvalue() == stream.getvalue().splitlines()[0] + "\n" and "2.00 s simulated" in stream.getvalue()
