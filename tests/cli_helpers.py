"""Run the installed ``facestats`` console script in a subprocess."""

import os
import pathlib
import shutil
import subprocess
import sys


def facestats_exe():
    exe = pathlib.Path(sys.executable).parent / "facestats"
    if exe.exists():
        return [str(exe)]
    found = shutil.which("facestats")
    if found:
        return [found]
    return [sys.executable, "-m", "facestats"]


def run_cli(*args, cwd=None, timeout=600, env=None):
    e = dict(os.environ, MPLBACKEND="Agg", PYTHONWARNINGS="ignore")
    if env:
        e.update(env)
    return subprocess.run(
        facestats_exe() + [str(a) for a in args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
        env=e,
        stdin=subprocess.DEVNULL,
    )
