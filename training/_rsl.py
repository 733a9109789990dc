"""Imported before `rsl_rl`: its logger imports GitPython at module level, which fails where no git
binary is found unless GIT_PYTHON_REFRESH says to stay quiet."""

import os

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")
