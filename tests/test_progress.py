"""facestats.core.progress: bars shown when asked for, on any stderr; FACESTATS_PROGRESS=0 hides them all."""

import io
import sys

import pytest

from facestats.core.progress import PROGRESS_ENV, progress_bar


@pytest.mark.parametrize(("enabled", "env", "shown"), [(True, None, True), (False, None, False), (True, "0", False)])
def test_a_bar_is_shown_when_asked_for_unless_the_environment_hides_it(monkeypatch, enabled, env, shown):
    err = io.StringIO()  # not a terminal
    monkeypatch.setattr(sys, "stderr", err)
    if env is None:
        monkeypatch.delenv(PROGRESS_ENV, raising=False)
    else:
        monkeypatch.setenv(PROGRESS_ENV, env)
    assert sum(progress_bar(range(5), enabled=enabled, desc="work", unit="step")) == 10  # iterates either way
    assert ("work: 100%" in err.getvalue()) is shown and ("5/5" in err.getvalue()) is shown


def test_a_hidden_bar_is_no_tqdm_and_takes_no_lock(monkeypatch):
    """tqdm's write lock is shared with forked processes: a process that shows no bar must never take it."""
    import tqdm

    monkeypatch.setenv(PROGRESS_ENV, "0")
    taken = []
    monkeypatch.setattr(tqdm.tqdm, "get_lock", classmethod(lambda cls: taken.append(1)))
    bar = progress_bar(range(3), enabled=True, total=3)
    assert list(bar) == [0, 1, 2] and len(bar) == 3 and not isinstance(bar, tqdm.tqdm)
    with progress_bar(total=5, enabled=True, initial=2) as manual:
        manual.update(2)
        assert manual.n == 4
    assert taken == []


class _Terminal(io.StringIO):
    def isatty(self):
        return True


@pytest.mark.parametrize(("stream", "interval"), [(io.StringIO, 30.0), (_Terminal, None)])
def test_a_bar_written_to_a_log_is_redrawn_seldom(monkeypatch, stream, interval):
    """To a file or a pipe a bar is redrawn every LOG_INTERVAL_S seconds at most, its first and last states always:
    a validate of the default store wrote about 150 carriage-return updates into a log (a user's walkthrough)."""
    from facestats.core.progress import LOG_INTERVAL_S

    err = stream()
    monkeypatch.setattr(sys, "stderr", err)
    monkeypatch.delenv(PROGRESS_ENV, raising=False)
    clock = iter(range(0, 10_000, 1))  # every step takes 1 s: a terminal bar redraws at each, a logged one at 30
    monkeypatch.setattr("tqdm.std.time", lambda: float(next(clock)))
    with progress_bar(total=100, desc="work") as bar:
        for _ in range(100):
            bar.update(1)
    draws = err.getvalue().count("\r")
    if interval is None:
        assert draws > 50, draws
    else:
        assert LOG_INTERVAL_S == interval and 2 <= draws <= 2 + 100 // int(interval) + 1, draws
    assert "work: 100%" in err.getvalue()


class _KernelStream(io.StringIO):
    """Stands for ipykernel's OutStream (a notebook's stderr), whose isatty() is False."""


_KernelStream.__module__ = "ipykernel.iostream"


def test_a_notebooks_text_bar_is_live_and_no_stderr_hides_the_bar(monkeypatch):
    """In a Jupyter kernel without ipywidgets tqdm.auto draws text on the kernel's stderr, which is no terminal but
    shown live: it was redrawn every LOG_INTERVAL_S seconds there (an nbclient kernel, 2026-12-08).  With no stderr
    at all (pythonw) the bar raised AttributeError on its first draw."""
    monkeypatch.delenv(PROGRESS_ENV, raising=False)
    monkeypatch.setattr(sys, "stderr", _KernelStream())
    with progress_bar(total=3, desc="work") as bar:
        assert bar.mininterval == 0.1  # tqdm's own default, not LOG_INTERVAL_S
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    with progress_bar(total=3, desc="work") as bar:
        assert bar.mininterval == 30.0
    monkeypatch.setattr(sys, "stderr", None)
    assert sum(progress_bar(range(5), desc="work")) == 10
