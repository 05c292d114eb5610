"""Test-wide settings. Hypothesis runs derandomized so CI sees the same examples on every machine
(a property that fails on some example is then a reproducible failure, not a flake); set
HYPOTHESIS_PROFILE=explore to search new examples locally."""
import os
import sys

from hypothesis import settings

settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
settings.register_profile("explore", deadline=None, print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

sys.path.insert(0, os.path.dirname(__file__))  # tests/meshes.py
