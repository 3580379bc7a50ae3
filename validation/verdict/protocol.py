"""The comparison protocol, in one place: every test, sweep, table and `validate check` uses these.

ALPHA is the family-wise false-positive rate of one comparison (all blocks and channels of one image);
seeds are bases that keep the streams of the different uses of one scene apart, so that a test image is
never correlated with the reference it is compared with.
"""
from __future__ import annotations

ALPHA = 1e-3        # family-wise false-positive rate of one comparison
PASSES = 16         # independent passes of each renderer
SIZE = 32           # longer side of the image a check renders (the scene's aspect ratio kept)
BLOCK = 4           # the test's blocks are BLOCK x BLOCK pixels
SPP = 64            # samples per pixel of one pass (path estimators and Mitsuba)
REPORT_SPP = 2      # camera rays per pixel of one pass of the branching (report) estimator
MAX_SPP = 8192      # a check that cannot decide raises the spp per pass up to this (validation.verdict.check.run)
CI_MARGIN = 0.01    # validate check's equivalence margin of the image mean where CI is set (README: in CI)
BLOCK_MARGIN = 0.2  # equivalence margin per block (of its mean, or the image mean where darker): calibration.md

# Seed bases. Pass k of a use draws seed BASE + k (tracer) or BASE * 1_000_003 + k (Mitsuba).
SEED_TEST = 1000        # the renderer under test
SEED_REFERENCE = 777    # Mitsuba references (cached)
SEED_SWEEP = 1          # report sweeps: spec.seed * 1000 + k
SEED_NULL = 50_000      # calibration: null comparisons, one base per repetition above this
SEED_STABILITY = 4242   # the numerical stability suite
