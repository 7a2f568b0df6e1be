"""The kind and behaviour records (biped_switch.kinds): the tables derived from them, the fixed
random streams that keep every existing track byte for byte, and what a new kind leaves alone.
Pure numpy: fast."""

from __future__ import annotations

import dataclasses
import hashlib
import json

import numpy as np
import pytest

from biped_switch import kinds, lineups, names
from biped_switch.config import default_terrain_config
from biped_switch.simulation import terrain

# sha256[:16] of json.dumps(track.to_json(), sort_keys=True) at difficulty 1 and 0.4, and of the
# segment table + artifact codes + spans, taken from the generator before the kind records existed
PINNED = {
    (10000, "walk"): ("b54b9f1ea44dc2d1", "cb793383f4f06ad2", "0dfafb6ed8d4a9d9"),
    (10000, "jumps"): ("24484394512eedfc", "8257a85580aee5e4", "ba958e5410c2509f"),
    (10000, "gaps"): ("c319045d79abc09c", "b2fdb5a3e5e99c4e", "f145284b3ab4ea69"),
    (10000, "stairs"): ("033ae704b2d661ec", "306bcc653b607b90", "ced5746a7501c57f"),
    (10000, "mixed"): ("5e5746834c2c17e9", "a18e90e3927c6729", "b3613b1c8c2a10d2"),
    (30000, "walk"): ("8d31d2fb7833dfdc", "4a5834a92d2eceea", "63b57d6f669e94ad"),
    (30000, "jumps"): ("9dbbe6fec75b9b57", "e764ff9499383be6", "e72799278d87d8c0"),
    (30000, "gaps"): ("80eea3e9e8532f31", "d8b653997041b3d5", "2ae13b57f101c94b"),
    (30000, "stairs"): ("16c69b129fed4fc1", "0be8c0c7471df95c", "ea58f75208384196"),
    (30000, "mixed"): ("53f386310802aef7", "e763b9b9214faed1", "ca9a7dc048f8de3c"),
    (50000, "walk"): ("43d24ad3fad419c9", "c5c05b3cdace36c6", "14c32a91ffbf2662"),
    (50000, "jumps"): ("462e127878403380", "9d5292a76ac56014", "64d8038828b71772"),
    (50000, "gaps"): ("4055a36b1d38c4e5", "0b536bd4c64cf970", "6b69f613e8e23c94"),
    (50000, "stairs"): ("495cbb1b374cb45f", "4ceb109ef771f760", "003eb5411b85221f"),
    (50000, "mixed"): ("b2f83b56f50b2761", "0cc95afabbf2c634", "fd03e0c30e95dc36"),
}
PINNED_SEQUENCE = "52fe5518c8a6fe08"  # sequence_track(7, ["gaps", "stairs", "jumps"])


def _sha(b: bytes) -> str:
    return hashlib.sha256(b).hexdigest()[:16]


def _hashes(seed, kind):
    t1, t04 = (terrain.generate_track(seed, kind, d) for d in (1.0, 0.4))
    js = [_sha(json.dumps(t.to_json(), sort_keys=True).encode()) for t in (t1, t04)]
    seg = _sha(t1.segments.tobytes() + t1.artifact_codes.tobytes()
               + t1.artifact_segments.tobytes())
    return (*js, seg)


def _check_pinned():
    got = {key: _hashes(*key) for key in PINNED}
    assert got == PINNED
    seq = terrain.sequence_track(7, ["gaps", "stairs", "jumps"])
    assert _sha(json.dumps(seq.to_json(), sort_keys=True).encode()) == PINNED_SEQUENCE


def test_tracks_unchanged_byte_for_byte():
    _check_pinned()


def test_tables_from_the_records():
    assert names.ARTIFACT_KINDS == ("jumps", "gaps", "stairs")
    assert names.TERRAIN_KINDS == ("walk", "jumps", "gaps", "stairs", "mixed", "stones", "mixed4")
    assert kinds.PAPER_TERRAIN_KINDS == ("walk", "jumps", "gaps", "stairs", "mixed")
    assert names.POLICY_NAMES == ("walk", "jumps", "gaps", "stairs")
    assert names.POLICY_INDEX == {"walk": 0, "jumps": 1, "gaps": 2, "stairs": 3}
    assert names.DETECTOR_CLASSES == ("none", "jumps", "gaps", "stairs")
    assert kinds.ARTIFACT_CODE == {"jumps": 0, "gaps": 1, "stairs": 2}
    assert kinds.POLICY_OF_CODE == (1, 2, 3)
    assert kinds.CODE_OF_POLICY == (-1, 0, 1, 2)
    assert kinds.CLASS_OF_CODE == (1, 2, 3) and kinds.CODE_OF_CLASS == (-1, 0, 1, 2)
    assert kinds.WALK_POLICY == 0
    assert [kinds.policy_for(k) for k in ("walk", "jumps", "gaps", "stairs")] == [0, 1, 2, 3]
    assert {k: kinds.KIND[k].stream for k in names.TERRAIN_KINDS} == {
        "walk": 0, "jumps": 1, "gaps": 2, "stairs": 3, "mixed": 4, "stones": 5, "mixed4": 6}
    # one colour per kind, the figures' convention (gaps purple, stairs brown) everywhere
    assert kinds.KIND_COLOURS["gaps"] == "tab:purple" and kinds.KIND_COLOURS["stairs"] == "tab:brown"
    assert all(kinds.POLICY_COLOURS[b.crosses] == kinds.KIND_COLOURS[b.crosses]
               for b in kinds.BEHAVIOURS if b.crosses)


@pytest.mark.parametrize("kind", names.TERRAIN_KINDS)
def test_stream_is_the_records_stream_id(kind):
    """A track's first draw (its width) is the first draw of default_rng([seed, stream])."""
    cfg = default_terrain_config()
    for seed in (0, 123, 30_000):
        want = np.random.default_rng([seed, kinds.KIND[kind].stream]).uniform(
            cfg.width_min_m, cfg.width_max_m)
        assert terrain.generate_track(seed, kind).width_m == want


def test_fifth_kind_is_opted_in_only():
    """`stones` (issue 57) is in the ALL_ tables the generator and `train` read, and in none of
    the paper suite's (so the committed 4-policy suites, 3-class detectors, the DQN's one-hot and
    Table II stay as they were); the paper's tables above are unchanged."""
    assert kinds.ALL_ARTIFACT_KINDS == ("jumps", "gaps", "stairs", "stones")
    assert kinds.ALL_ARTIFACT_CODE == {"jumps": 0, "gaps": 1, "stairs": 2, "stones": 3}
    assert kinds.ALL_POLICY_NAMES == ("walk", "jumps", "gaps", "stairs", "stones")
    assert names.TRAIN_KINDS == ("walk", "jumps", "gaps", "stairs", "stones", "mixed")
    assert kinds.policy_for("stones") == 4 and kinds.KIND["stones"].colour not in {
        k.colour for k in kinds.TERRAIN if k.name != "stones"}
    assert kinds.KIND["mixed4"].artifacts == ("jumps", "gaps", "stairs", "stones")
    from biped_switch.simulation.observation import ONE_HOT_SIZE
    from biped_switch.switching.detector import CLASSES
    assert ONE_HOT_SIZE == 3 and len(CLASSES) == 4
    t = terrain.generate_track(40_000, "stones")
    assert t.artifact_codes.tolist() == [3] * 7 and {a[0] for a in t.artifacts} == {"stones"}


def test_paper_kinds_take_the_first_codes_and_slots():
    t, b = kinds.TERRAIN, kinds.BEHAVIOURS
    def swap(records):  # stairs out of the paper's suite, stones in
        return tuple(dataclasses.replace(r, paper=not r.paper) if r.name in ("stairs", "stones")
                     else r for r in records)
    with pytest.raises(ValueError, match="first codes.*first policy slots"):
        kinds.check(swap(t), swap(b))
    with pytest.raises(ValueError, match="paper kind mixed lays"):
        kinds.check(tuple(dataclasses.replace(k, artifacts=k.artifacts + ("stones",))
                          if k.name == "mixed" else k for k in t), b)
    with pytest.raises(ValueError, match="paper behaviour"):
        kinds.check(t, b[:-1] + (dataclasses.replace(b[-1], paper=True),))


def _ramps(rng, cfg, n):
    return [[rng.uniform(cfg.flat_min_m, cfg.flat_max_m), 0.0, 0.05 * k, 1.0] for k in range(n)]


def test_a_new_kind_relays_no_existing_track(monkeypatch):
    """A hypothetical sixth artifact kind, listed before `mixed` (where a positional stream id
    would have moved mixed), leaves every pinned track as it was."""
    ramps = kinds.TerrainKind("ramps", stream=7, colour="tab:cyan", singular="ramp",
                              artifacts=("ramps",), code=4, detector_class=5, paper=False)
    new_terrain = kinds.TERRAIN[:4] + (ramps,) + kinds.TERRAIN[4:]
    new_behaviours = kinds.BEHAVIOURS + (kinds.Behaviour("ramps", 5, "ramps", "tab:cyan",
                                                         paper=False),)
    kinds.check(new_terrain, new_behaviours)
    monkeypatch.setattr(kinds, "KIND", {k.name: k for k in new_terrain})
    monkeypatch.setattr(kinds, "ALL_ARTIFACT_CODE", {**kinds.ALL_ARTIFACT_CODE, "ramps": 4})
    monkeypatch.setattr(kinds, "ALL_ARTIFACT_KINDS", kinds.ALL_ARTIFACT_KINDS + ("ramps",))
    monkeypatch.setattr(terrain, "BUILDERS", {**terrain.BUILDERS, "ramps": _ramps})
    terrain.check_builders()
    _check_pinned()
    t = terrain.generate_track(10_000, "ramps")
    assert [a[0] for a in t.artifacts] == ["ramps"] * default_terrain_config().n_artifacts
    assert set(t.artifact_codes.tolist()) == {4}


def test_inconsistent_records_are_refused():
    t, b = kinds.TERRAIN, kinds.BEHAVIOURS
    dup_stream = t[:1] + (dataclasses.replace(t[1], stream=0),) + t[2:]
    with pytest.raises(ValueError, match="stream"):
        kinds.check(dup_stream, b)
    with pytest.raises(ValueError, match="codes"):
        kinds.check(t[:1] + (dataclasses.replace(t[1], code=5),) + t[2:], b)
    with pytest.raises(ValueError, match="one behaviour per artifact"):
        kinds.check(t, b[:-1])
    with pytest.raises(ValueError, match="policy indices"):
        kinds.check(t, b[:-1] + (dataclasses.replace(b[-1], index=7),))
    with pytest.raises(ValueError, match="builders"):
        terrain.check_builders({"jumps": None, "gaps": None})


def test_a_behaviour_tied_to_no_terrain_gets_a_slot_and_moves_no_mapping():
    """A sixth behaviour that crosses nothing (e.g. a recovery policy) is valid; walk stays the
    flat-ground policy and every kind keeps its policy."""
    extra = kinds.BEHAVIOURS + (kinds.Behaviour("recover", 5, None, "tab:cyan", trains_on="mixed",
                                                       paper=False),)
    kinds.check(kinds.TERRAIN, extra)
    pols = sorted(extra, key=lambda b: b.index)
    assert next(b.index for b in pols if b.crosses is None) == kinds.WALK_POLICY == 0
    with pytest.raises(ValueError, match="not a terrain kind"):
        kinds.check(kinds.TERRAIN, kinds.BEHAVIOURS + (kinds.Behaviour("recover", 5, None, "k", paper=False),))
    with pytest.raises(ValueError, match="cross nothing"):
        kinds.check(kinds.TERRAIN, kinds.BEHAVIOURS[1:])


@pytest.mark.parametrize("xp_name", ["numpy", "jax.numpy"])
def test_vectorised_lookups_by_hand(xp_name):
    xp = pytest.importorskip(xp_name)
    code = xp.asarray([-1, 0, 1, 2, -1, 3])  # 3: stones, outside the paper's suite: walk, none
    assert np.asarray(kinds.policy_of_code(code, xp)).tolist() == [0, 1, 2, 3, 0, 0]
    assert np.asarray(kinds.class_of_code(code, xp)).tolist() == [0, 1, 2, 3, 0, 0]
    assert np.asarray(kinds.code_of_class(xp.asarray([0, 1, 2, 3]), xp)).tolist() == [-1, 0, 1, 2]


def test_lineups_by_hand():
    """The paper's line-up is the paper=True records; the stones line-up adds stones as slot 4 and
    target 3 (its artifact code), so a code maps to the same policy in both where both know it."""
    paper, stones = lineups.LINEUP["paper"], lineups.LINEUP["stones"]
    assert (paper.policies, paper.targets) == (kinds.POLICY_NAMES, kinds.ARTIFACT_KINDS)
    assert paper.policy_of_code == kinds.POLICY_OF_CODE == (1, 2, 3)
    assert stones.policy_of_code == (1, 2, 3, 4) and stones.walk_policy == paper.walk_policy == 0
    assert (stones.n_policies, stones.n_targets, stones.tracks) == (5, 4, "mixed4")
    code = np.asarray([-1, 0, 1, 2, 3])
    assert lineups.policy_of_code(code, np, stones).tolist() == [0, 1, 2, 3, 4]
    assert lineups.policy_of_code(code, np, paper).tolist() == [0, 1, 2, 3, 0]


def test_inconsistent_lineups_are_refused():
    t, b, s = kinds.TERRAIN, kinds.BEHAVIOURS, lineups.LINEUPS
    bad = {
        "slots 0..n-1": dataclasses.replace(s[1], policies=("walk", "gaps", "jumps", "stairs", "stones")),
        "codes 0..m-1": dataclasses.replace(s[1], targets=("jumps", "gaps", "stones", "stairs")),
        "one per target": dataclasses.replace(s[1], policies=("walk", "jumps", "gaps", "stairs")),
        "must lay its targets": dataclasses.replace(s[1], tracks="mixed"),
    }
    for why, suite in bad.items():
        with pytest.raises(ValueError, match=why):
            lineups.check(t, b, (s[0], suite))
    with pytest.raises(ValueError, match="start with 'paper'"):
        lineups.check(t, b, s[::-1])
    with pytest.raises(ValueError, match="paper=True records"):
        lineups.check(t, b, (dataclasses.replace(s[1], name="paper"),))


def test_every_lineup_has_its_own_reporting_and_tuning_tracks():
    """Each line-up's Table II has reporting and tuning seeds (config.LINEUP_TRACK_SEEDS), the
    paper's the Table II / tuning ones, and no two ranges of 2,500 tracks overlap."""
    from biped_switch import config

    seeds = config.LINEUP_TRACK_SEEDS
    assert set(seeds) == set(lineups.LINEUP)
    assert seeds["paper"] == (config.MULTI_TRACK_SEED, config.TUNE_TRACK_SEED)
    starts = sorted(s for pair in seeds.values() for s in pair)
    assert all(b - a >= 2500 for a, b in zip(starts, starts[1:])), starts
