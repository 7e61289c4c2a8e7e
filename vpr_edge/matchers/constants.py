"""Every constant of the matchers' models, named once: the numbers that are not parameters (``params``: what a
user sets with ``--param``) but part of how a rule is built. Each says what it is; docs/decisions.md says what
each was chosen on, and the modules that use them import them from here.
"""
from __future__ import annotations

# --- the motion cue (``motion``) ---------------------------------------------------------------------------
MIN_STEPS = 3        # moving frames seen before their median step is trusted (before: those frames move)
MEMORY = 30          # moving frames whose median step is the typical one (the ``still_memory`` parameter's default)

# --- how far along a map references stay alike (``likeness``) ----------------------------------------------
SAMPLE = 2048        # references the estimate reads, from the route's start
MAX_LAG = 64         # the longest reach measured
PAIRS = 2048         # pairs per lag (and of unrelated references) at most

# --- the lock's rules (``lock``) ---------------------------------------------------------------------------
OFF = -99.0          # the value of ``evidence`` or ``hub`` that turns that line off (their help says "-99 = off")

# --- the road matcher's searches (``road``) -----------------------------------------------------------------
LOCAL_ROUTE = 4      # a local search runs on routes of more than this many windows (shorter: the whole route)
FIRM_RIVAL = 0.5     # a lock is firm while no trajectory beyond the window has this share of its score
PEAK_POOL = 4        # the best hypotheses held are chosen among this many times ``peaks`` of the highest places
PEAK_SPACING = 2     # ... each more than this many neighbourhoods from a better one
MIN_SPREAD = 1e-12   # the smallest spread a frame's similarities are z-scored with (a flat row)

# --- stream-prob's model of "not this place" (``verdict``, ``probability``) ---------------------------------
# the line: answers whose probability of being right is below this are lost (``--target-precision``)
TARGET_PRECISION = 0.98
# rival peaks whose spacings estimate the null's tail scale in one frame (the highest ones)
TAIL_PEAKS = 16
# frames whose spacings are pooled into the tail scale (an exponential memory)
TAIL_MEMORY = 100.0
# the view's Beta(a, 1) model: a's prior value and its weight in frames, the trajectory probability above
# which a frame teaches it, and the range it is kept in
VIEW_PRIOR, VIEW_PRIOR_FRAMES, VIEW_LEARN, VIEW_RANGE = 0.5, 10.0, 0.9, (0.02, 1.0)
# frames of the view's learning pooled (an exponential memory)
VIEW_MEMORY = 200.0
# the filter's prior rates per frame: leaving the answer's place (a detour, a lost track), coming onto it
LEAVE, ENTER = 0.01, 0.05
# the view's recent means (``RecentViews``): frames of memory (an exponential one, per sighting) and the
# prior's weight in frames of mean 0
HUB_MEMORY, HUB_PRIOR = 10.0, 1.0
# an answer within this many places of the place (along the route) is right: the place's probability sums the
# hypotheses that near the answer (the shared datasets' ground truth lists each frame's place +-2)
ANSWER_SLACK = 2
# the places near the answer are hypotheses of their own, weighed with this share of the null's tail scale
# (chosen on nordland-dev: the most answers whose median precision over its streams and five front ends
# reaches the target; Corridor's choice would be 0.7; docs/decisions.md)
PLACE_SCALE = 0.6
# frames whose probabilities the line reads (``expected_precision``): the last this many
LINE_MEMORY = 500
# no answer less sure than this is given, whatever the precision of the answers as sure as it: a vehicle acts
# on each answer, and after a long sure stretch the mean over "at least as sure" stays high for a while
ANSWER_FLOOR = 0.9
# a lock is firm (a local search may follow it) at this trajectory probability
FIRM = 0.999
# one rival holds most of the doubt ("ambiguous" rather than "no-trajectory") at this share of the rivals' weight
DOUBT_SHARE = 0.5
# the decoy's gate (``DecoyGate``, the ``decoy`` parameter): frames in the mean of (best - decoy best), the line
# on it in spreads of the recent decoy bests, the frames of that spread, and the frames that tell forwards from
# backwards before the gate can open (2: the fewest a spread is read from)
DECOY_MEMORY, DECOY_LINE, DECOY_SPREAD, DECOY_WARM = 40.0, 0.5, 51, 2

# --- the SVM baseline (``svm``) -----------------------------------------------------------------------------
SVM_C = 1.0          # the linear SVMs' regularisation (scikit-learn's default)

# --- the ``stream`` filter (``bayes``) ----------------------------------------------------------------------
START_OFF = 0.5          # the prior probability of being off the map at a stream's first frame
JOIN = 0.5               # the share of a junction's source places' mass that crosses into its targets each frame
# the likelihood's scale (the mean z-score of the true place): its prior and the prior's weight in frames, and
# the range it is kept in (a sanity bound, not a fit)
SCALE_PRIOR, SCALE_PRIOR_FRAMES, SCALE_BOUNDS = 2.0, 10.0, (0.5, 8.0)
HUB_DELAY = 8            # frames a frame's z-scores wait before they join the hub means (the passing place's view)
CUE_FLOOR = 0.05        # the motion cue's weight of the speed it contradicts (the cue may be wrong)
