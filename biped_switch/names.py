"""The enumerations every stage shares: terrain kinds, policies, inits, physics backends and
switching methods. Plain Python, importing nothing, so the reports layer stays free of JAX."""

ARTIFACT_KINDS = ("jumps", "gaps", "stairs")  # index = artifact code used in arrays
TERRAIN_KINDS = ("walk",) + ARTIFACT_KINDS + ("mixed",)  # track kinds the terrain generator lays
POLICY_NAMES = ("walk",) + ARTIFACT_KINDS  # index = artifact code + 1
POLICY_INDEX = {n: i for i, n in enumerate(POLICY_NAMES)}
TRAIN_KINDS = POLICY_NAMES + ("mixed",)  # what `train --policy` accepts (mixed: end-to-end)
INITS = ("stand", "random")  # the start of every episode: standing pose, or random joints
BACKENDS = ("mujoco", "mjx")  # C engine (fast on a CPU) | MJX (an accelerator)
BACKEND_CHOICES = ("auto",) + BACKENDS  # what every CLI's --backend accepts

# Table II's rows: the paper's switching methods, its baselines, and ours beside them.
SWITCH_METHODS = ("random", "detection", "lookup", "com_over_feet", "estimator",
                  "estimator_no_overlap")
BASELINES = ("dqn", "end_to_end")  # trained on the whole mixed domain
# Ours, beyond the paper: lookup table and estimators from the context sweeps (`sweep --context`),
# whose switches come after the source policy's own artifact, as on these tracks.
# `estimator_context_persist` also asks for the estimate to hold for PERSIST_STEPS control steps
# in a row (as long as a sweep sample's window) instead of the paper's first confident step.
CONTEXT_METHODS = ("lookup_context", "estimator_context", "estimator_context_persist")
# Ours with setup policies (switching/setup.py): a method of the rows above, and where a trained
# setup policy exists for (active policy -> target), it acts from detection to its hand-over.
# `learned_setup`: the learned rule below with the setup policies (a pair without one: the rule).
SETUP_METHODS = ("lookup_context_setup", "learned_setup")
# Ours: the learned "when" rule (switching/when.py), trained on the context sweeps' approaches;
# `learned_no_overlap` is the same rule on the random-init suite (estimator_no_overlap's like).
LEARNED_METHODS = ("learned", "learned_no_overlap", "learned_setup")
RANDOM_INIT_METHODS = ("estimator_no_overlap", "learned_no_overlap")  # random-init suite, start
MULTI_METHODS = tuple(dict.fromkeys(SWITCH_METHODS + BASELINES + CONTEXT_METHODS + SETUP_METHODS
                                    + LEARNED_METHODS))
# What the terrain detector names: nothing in range, or an artifact kind (class c = kind + 1).
DETECTOR_CLASSES = ("none",) + ARTIFACT_KINDS
HEURISTICS = ("random", "detection", "lookup", "com_over_feet")  # the paper's heuristic rows

# The fields of one traced trial (`evaluate multi --fig5-trial`), as Fig. 5 reads them.
FIG5_KEYS = ("time_s", "com_x_m", "body_com", "soles", "contact", "det_kind", "det_dist_m",
             "est_probs", "com_ok", "active", "switched", "ended", "fell", "success", "track_seed")
