"""Every constant of the matchers' models, named once: the numbers that are not parameters (``params``: what a
user sets with ``--param``) but part of how a rule is built. Each says what it is; docs/decisions.md says what
each was chosen on, and the modules that use them import them from here.
"""
from __future__ import annotations

# --- the motion cue (``motion``) ---------------------------------------------------------------------------
REPEAT_STEP = 1e-9   # a step (1 - cosine) this small: the anchor's encoding again, bit for bit (a duplicated frame)
MIN_STEPS = 3        # moving frames seen before their median step is trusted (before: those frames move)
MEMORY = 30          # moving frames whose median step is the typical one (the ``still_memory`` parameter's default)

# --- how far along a map references stay alike (``likeness``) ----------------------------------------------
SAMPLE = 2048        # references the estimate reads, from the route's start
MAX_LAG = 64         # the longest reach measured
PAIRS = 2048         # pairs per lag (and of unrelated references) at most

# --- the lock's rules (``lock``) ---------------------------------------------------------------------------
OFF = -99.0          # the value of ``evidence`` or ``hub`` that turns that line off (their help says "-99 = off")
# the hub line's recent views (``lock.RecentViews``): frames of memory (an exponential one, per sighting) and
# the prior's weight in frames of mean 0
HUB_MEMORY, HUB_PRIOR = 10.0, 1.0

# --- the road matcher's searches (``road``) -----------------------------------------------------------------
LOCAL_ROUTE = 4      # a local search runs on routes of more than this many windows (shorter: the whole route)
FIRM_RIVAL = 0.5     # a lock is firm while no trajectory beyond the window has this share of its score
PEAK_POOL = 4        # the best hypotheses held are chosen among this many times ``peaks`` of the highest places
PEAK_SPACING = 2     # ... each more than this many neighbourhoods from a better one
MIN_SPREAD = 1e-12   # the smallest spread a frame's similarities are z-scored with (a flat row)

# --- the lost line of a matcher whose score is a probability (``stream``) ----------------------------
# answers whose probability of being right is below this are lost (``--target-precision``); also the
# precision at which ``evaluate`` reads every mode's best line
TARGET_PRECISION = 0.98

# --- the SVM baseline (``svm``) -----------------------------------------------------------------------------
SVM_C = 1.0          # the linear SVMs' regularisation (scikit-learn's default)

# --- the ``stream`` filter (``bayes``) ----------------------------------------------------------------------
START_OFF = 0.5          # the prior probability of being off the map at a stream's first frame
JOIN = 0.5               # the share of a fork's source places' mass that crosses into its targets each frame
# the likelihood's scale (the mean z-score of the true place): its prior and the prior's weight in frames, and
# the range it is kept in (a sanity bound, not a fit)
SCALE_PRIOR, SCALE_PRIOR_FRAMES, SCALE_BOUNDS = 2.0, 10.0, (0.5, 8.0)
# the percentile the upper tail of a frame's similarities is read to (``bayes.robust_z``): chosen on nordland-dev
# against 90 and 97.5 (docs/decisions.md, "The stream filter's parameters")
TAIL_QUANTILE = 95.0
# a frame's z-scores count up to the likelihood's scale plus Z_CAP (the true place's z-score is normal about the
# scale, sd 1): a spike beyond what the true place gives (a place that looks like anything) is no more evidence.
# Chosen on nordland-dev among 2-5 (docs/decisions.md, "The stream filter's parameters")
Z_CAP = 2.0
HUB_DELAY = 8            # frames a frame's z-scores wait before they join the hub means (the passing place's view)
# without a motion cue (``filter_motion.blind``): a stopped camera starts again at one place a frame with this
# probability a frame; chosen on nordland-dev's pixels (docs/decisions.md, "The stream filter's parameters")
GO_BLIND = 0.1
# a camera slower than the map's drive (``filter_motion.speed_values``): SLOW_SPEED places a frame, reached from
# standing or from one place a frame with probability SLOW_CHANGE a frame (left as any speed is, by
# ``speed_change``). Rare: a stop with a repeated view is read by the motion cue. Chosen on nordland-dev
# (docs/decisions.md, "The stream filter's parameters")
SLOW_SPEED, SLOW_CHANGE = 0.5, 0.001
MAX_PHASES = 4          # a speed's fraction of a place is a multiple of 1/n, n at most this (its cycle's length)
REPEAT = 1.0 - 1e-6     # a motion cue this high (a copy reads 1: REPEAT_STEP): a duplicated frame, skipped
CUE_FLOOR = 0.05        # the motion cue's weight of the speed it contradicts (the cue may be wrong)
# the stream filter reads the motion cue as a normal about CUE_STANDING[0] (sd CUE_STANDING[1]) where the camera
# stands and about 0 (sd CUE_MOVING_SD) where it moves (``filter_motion.cue_weights``); chosen on nordland-dev
# (docs/decisions.md, "The stream filter's parameters")
CUE_STANDING = (0.75, 0.15)
CUE_MOVING_SD = 0.3
