"""Test configuration: CI runs hypothesis derandomized (the same examples every run), so a red CI is
reproducible; local runs keep exploring new examples."""

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")
