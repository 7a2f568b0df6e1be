"""The enumerations every stage shares: terrain kinds, policies, inits, physics backends and
switching methods. Plain Python (the kind and behaviour tables come from the records in
kinds.py), so the reports layer stays free of JAX."""

# index = artifact code | every track kind | index = policy slot (kinds.py: the records)
# (the paper's suite; ALL_: every record, kinds outside the paper's suite too)
from biped_switch.kinds import ARTIFACT_KINDS, TERRAIN_KINDS, POLICY_NAMES, POLICY_INDEX  # noqa: F401
from biped_switch.kinds import ALL_ARTIFACT_KINDS, ALL_POLICY_NAMES  # noqa: F401
TRAIN_KINDS = ALL_POLICY_NAMES + ("mixed",)  # what `train --policy` accepts (mixed: end-to-end)
INITS = ("stand", "random")  # the start of every episode: standing pose, or random joints
BACKENDS = ("mujoco", "mjx")  # C engine (fast on a CPU) | MJX (an accelerator)
BACKEND_CHOICES = ("auto",) + BACKENDS  # what every CLI's --backend accepts

# Table II's rows, each a record of biped_switch/methods.py (what it runs and needs); these
# tuples of their names are read off the records.
from biped_switch import methods as _methods  # noqa: E402  (plain Python, imports nothing)

SWITCH_METHODS = _methods.names(lambda m: m.whose == "paper" and not m.baseline)
BASELINES = _methods.names(lambda m: m.baseline)  # trained on the whole mixed domain
# ours from the context sweeps (`sweep --context`): switches come after the source's own artifact
CONTEXT_METHODS = _methods.names(lambda m: "context" in (m.lookup, m.estimators) and not m.setup)
SETUP_METHODS = _methods.names(lambda m: m.setup)  # ours with setup policies (switching/setup.py)
LEARNED_METHODS = _methods.names(lambda m: m.when)  # the learned when rule (switching/when.py)
RANDOM_INIT_METHODS = _methods.names(lambda m: m.suite == "random")  # random-init suite, start
MULTI_METHODS = _methods.names()
HEURISTICS = _methods.names(lambda m: m.heuristic)  # the paper's heuristic rows
# What the terrain detector names: nothing in range, or an artifact kind (kinds.CLASS_OF_CODE).
from biped_switch.kinds import DETECTOR_CLASSES  # noqa: E402,F401

# The fields of one traced trial (`evaluate multi --fig5-trial`), as Fig. 5 reads them.
FIG5_KEYS = ("time_s", "com_x_m", "body_com", "soles", "contact", "det_kind", "det_dist_m",
             "est_probs", "com_ok", "active", "switched", "ended", "fell", "success", "track_seed")
