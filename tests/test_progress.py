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
