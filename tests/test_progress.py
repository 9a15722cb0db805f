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
