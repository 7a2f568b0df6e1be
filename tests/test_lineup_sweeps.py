"""Context sweeps and lookup tables of a line-up other than the paper's (lineups.Lineup "stones": five
policies, four targets, mixed4 tracks): the plan, names and tables by hand, the paper's left as
they were, and the command line's refusals. No rollout: the sweep's env, suite and batch are the
stand-ins of test_sweep.py's `fake_sweep`."""

from __future__ import annotations

import json
import types

import numpy as np
import pytest

from biped_switch import kinds, lineups
from biped_switch import sweep as sweep_cli
from biped_switch.products import sweep as sweep_products
from biped_switch.simulation.observation import ObsLayout
from biped_switch.switching import lookup, sweep
from biped_switch.switching.estimator import sweep_name

from test_sweep import fake_sweep  # noqa: F401  (the fixture)

STONES, PAPER = lineups.LINEUP["stones"], lineups.PAPER_LINEUP


# ----------------------------------------------------------------------- names and plans
def test_sweep_names_keep_the_papers_and_name_other_lineups_apart():
    assert [sweep_name("stand"), sweep_name("stand", True), sweep_name("stand", True, True)] == [
        "stand", "stand_context", "stand_leadin"]
    assert sweep_name("stand", True, lineup=PAPER) == "stand_context"
    assert sweep_name("stand", True, lineup=STONES) == "stand_context_stones"
    assert sweep_name("random", lineup=STONES) == "random_stones"


def test_stones_context_plan_by_hand():
    """Into stones: sources walk, jumps, gaps, stairs (slots 0-3); walk's second artifact cycles
    over the other three targets. Into jumps: the stones policy (slot 4) is a source too, and
    walk's second artifact reaches stones."""
    kinds_s, src, tidx = sweep.context_plan("stones", 8, STONES)
    assert src.tolist() == [0, 1, 2, 3] * 2
    assert kinds_s == [["stones", "jumps"], ["jumps", "stones"], ["gaps", "stones"],
                       ["stairs", "stones"], ["stones", "gaps"], ["jumps", "stones"],
                       ["gaps", "stones"], ["stairs", "stones"]]
    assert tidx.tolist() == [0, 1, 1, 1] * 2
    kinds_j, src, tidx = sweep.context_plan("jumps", 12, STONES)
    assert src.tolist() == [0, 2, 3, 4] * 3
    sources = [["gaps", "jumps"], ["stairs", "jumps"], ["stones", "jumps"]]
    assert kinds_j == ([["jumps", "gaps"]] + sources + [["jumps", "stairs"]] + sources
                       + [["jumps", "stones"]] + sources)
    assert tidx.tolist() == [0, 1, 1, 1] * 3


def test_the_papers_plans_are_the_default_and_other_targets_are_refused():
    for plan in (sweep.context_plan, sweep.leadin_plan):
        kinds_a, src_a, tidx_a = plan("stairs", 9)
        kinds_b, src_b, tidx_b = plan("stairs", 9, PAPER)
        assert kinds_a == kinds_b and (src_a == src_b).all() and (tidx_a == tidx_b).all()
        assert set(src_a.tolist()) == {0, 1, 2}  # the paper's four policies but stairs
    with pytest.raises(ValueError, match="'stones'.*paper"):
        sweep.context_plan("stones", 4)
    with pytest.raises(ValueError, match="'mixed'.*stones"):
        sweep.context_plan("mixed", 4, STONES)


def test_the_runner_switches_into_the_slot_the_table_leaves_out():
    """make_runner's target (kinds.policy_for) and the lookup's target row are one slot."""
    for lu in lineups.LINEUPS:
        for t in lu.targets:
            assert lookup.target_slot(t, lu) == kinds.policy_for(t)
            assert lu.policies[lookup.target_slot(t, lu)] == kinds.BEHAVIOUR[t].name


def test_stones_context_env_lays_its_plan_on_its_track_kind():
    kinds_s, _, _ = sweep.context_plan("stones", 4, STONES)
    env = sweep.make_context_env(kinds_s, "stand", lineup=STONES, backend="mujoco")
    assert env.cfg.kind == "mixed4"
    codes = [[kinds.ALL_ARTIFACT_KINDS[c] for c in row] for row in env.bank.artifact_codes]
    assert codes == kinds_s
    with pytest.raises(ValueError, match="stones"):  # the paper's line-up cannot cross stones
        sweep.make_context_env(kinds_s, "stand", backend="mujoco")


def test_sweep_meta_names_its_lineup():
    assert sweep.sweep_lineup({}) == PAPER  # the paper's sweeps, and those made before line-ups
    assert sweep.sweep_lineup({"lineup": "stones"}) == STONES
    with pytest.raises(ValueError, match="'bogus'"):
        sweep.sweep_lineup({"lineup": "bogus"})


# ----------------------------------------------------------------------- lookup tables
def _stones_tables():
    """Into stones: walk (0) 1 of 2 at 0.305 m, stairs (3) 1 of 1 at 0.705 m, stones itself (4)
    data that is no switch. Into jumps: stones (4) 2 of 2 at 0.405 m, jumps itself (1) ignored."""
    into_stones = lookup.lookup_table(np.array([0.305, 0.305, 0.705, 0.5]), np.array([1, 0, 1, 1]),
                                      np.array([0, 0, 3, 4]), "stones", lineup=STONES)
    into_jumps = lookup.lookup_table(np.array([0.405, 0.405, 0.2]), np.array([1, 1, 1]),
                                     np.array([4, 4, 1]), "jumps", lineup=STONES)
    return {"jumps": into_jumps, "stones": into_stones}


def test_stones_lookup_tables_and_matrix_by_hand():
    t = _stones_tables()
    assert t["stones"]["rate"].shape == (5, 90)
    assert t["stones"]["rate"][0, 30] == 0.5 and t["stones"]["count"][0, 30] == 2
    np.testing.assert_allclose(t["stones"]["best_m"], [0.305, np.nan, np.nan, 0.705, np.nan])
    np.testing.assert_allclose(t["jumps"]["best_m"], [np.nan, np.nan, np.nan, np.nan, 0.405])
    m = lookup.lookup_matrix(t, STONES)
    want = np.full((5, 4), np.nan)
    want[0, 3], want[3, 3], want[4, 0] = 0.305, 0.705, 0.405
    np.testing.assert_allclose(m, want)
    with pytest.raises(ValueError, match="'stones'.*paper"):  # no stones column in the paper's
        lookup.lookup_matrix({"stones": t["stones"]}, PAPER)
    with pytest.raises(ValueError, match="5 rows.*paper"):  # nor a stones row
        lookup.lookup_matrix({"jumps": t["jumps"]}, PAPER)
    with pytest.raises(ValueError, match="4 rows.*stones"):  # a paper-sized table
        lookup.table_from_rates(np.zeros((4, 90)), np.zeros((4, 90)), "jumps", lineup=STONES)


def test_stones_lookup_files_are_named_apart_and_load_at_their_size(tmp_path):
    name = sweep_name("stand", True, lineup=STONES)
    assert lookup.context_lookup_missing("stand", tmp_path, STONES) is None
    with pytest.raises(FileNotFoundError, match="--context --lineup stones"):
        lookup.load_context_lookup("stand", tmp_path, STONES)
    doc = lookup.save_lookup(_stones_tables(), name, tmp_path, {}, STONES)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lookup_stand_context_stones.json"]
    assert len(doc["best_m"]) == 20 and doc["best_m"]["stones->jumps"] == 0.405
    assert doc["best_m"]["walk->stones"] == 0.305 and doc["best_m"]["gaps->stones"] is None
    m = lookup.load_lookup(name, tmp_path, STONES)
    assert m.shape == (5, 4) and m[4, 0] == 0.405 and m[3, 3] == 0.705
    with pytest.raises(ValueError, match=r"\(5, 4\).*paper"):
        lookup.load_lookup(name, tmp_path)
    # gaps and stairs not swept, and no plain stones lookup to fill them: refused, named
    assert lookup.lookup_missing(name, tmp_path, STONES) == ["gaps", "stairs"]
    assert lookup.context_lookup_missing("stand", tmp_path, STONES) == ["gaps", "stairs"]
    with pytest.raises(FileNotFoundError, match="gaps', 'stairs'.*--targets gaps stairs"):
        lookup.load_context_lookup("stand", tmp_path, STONES)
    # the paper's context lookup is another file, untouched by the stones one
    assert lookup.context_lookup_missing("stand", tmp_path) is None
    full = {**_stones_tables(), "gaps": _stones_tables()["jumps"] | {"best_m": np.full(5, 0.1)},
            "stairs": _stones_tables()["jumps"] | {"best_m": np.full(5, 0.2)}}
    lookup.save_lookup(full, name, tmp_path, {}, STONES)
    m, used = lookup.load_context_lookup("stand", tmp_path, STONES)
    assert m.shape == (5, 4) and m[4, 0] == 0.405 and (m[:, 1] == 0.1).all()
    assert used == [f"{k}: {tmp_path / 'lookup_stand_context_stones.json'}"
                    for k in STONES.targets]
    assert lookup.context_lookup_missing("stand", tmp_path, STONES) == []


# ----------------------------------------------------------------------- the command line
@pytest.mark.parametrize("argv,says", [
    (["--lineup", "stones"], "'stones': a plain sweep"),
    (["--lineup", "stones", "--lead-in"], "'stones': a lead-in sweep"),
    (["--lineup", "bogus", "--context"], "invalid choice: 'bogus'"),
    (["--context", "--targets", "stones"], "--targets stones: not a target of line-up paper"),
    (["--context", "--lineup", "stones", "--targets", "mixed4"], "invalid choice: 'mixed4'"),
])
def test_cli_refuses_a_bad_lineup_or_target(argv, says, capsys, tmp_path):
    with pytest.raises(SystemExit) as e:
        sweep_cli.main(argv + ["--out", str(tmp_path / "o"), "--results", str(tmp_path / "r")])
    assert e.value.code == 2 and says in capsys.readouterr().err
    assert not (tmp_path / "o").exists() and not (tmp_path / "r").exists()


def test_run_sweep_refuses_what_the_lineup_does_not_sweep(tmp_path):
    cfg = sweep_cli.default_sweep_config()
    with pytest.raises(ValueError, match="'stones'.*--context"):
        sweep.run_sweep("stand", "stones", cfg, tmp_path, lineup=STONES)
    with pytest.raises(ValueError, match="'stones'"):
        sweep.run_sweep("stand", "stones", cfg, tmp_path, context=True)
    assert list(tmp_path.iterdir()) == []


@pytest.fixture
def fake_context(fake_sweep, monkeypatch):  # noqa: F811
    """`fake_sweep`, and the context env recorded: (kinds per track, line-up) per call."""
    made = []

    def make_context_env(kinds_, init, difficulty=1.0, lineup=PAPER, **kw):
        made.append((kinds_, lineup))
        return types.SimpleNamespace(obs_layout=ObsLayout((2, 2)))

    monkeypatch.setattr(sweep, "make_context_env", make_context_env)
    return made


def test_cli_stones_context_sweep_writes_its_own_data_and_5_by_4_lookup(fake_context, tmp_path):
    """2 batches of 6 tracks 0..11 (tracks 0, 3, 6, 9 fall before the switch; labels 1 on even
    ids; switch at id cm + 0.5 cm), each track's source from the stones plan: ids 1..11 cycle
    over slots 0..3, so walk: ids 4, 8 both 1 (farthest: 0.085 m), jumps: 1, 5 both 0 (0.055),
    gaps: 2, 10 both 1 (0.105), stairs: 7, 11 both 0 (0.115); stones -> stones is no switch."""
    out, res = tmp_path / "sweeps", tmp_path / "lookup"
    argv = ["--context", "--lineup", "stones", "--points", "30", "--batch", "6", "--tracks",
            "1000", "--out", str(out), "--results", str(res), "--target", "stones"]
    assert sweep_cli.main(argv) == 0
    assert fake_context[0][1] == STONES
    assert fake_context[0][0] == sweep.context_plan("stones", 1000, STONES)[0]
    meta = json.loads((out / "stand_context_stones/stones/meta.json").read_text())
    assert meta["lineup"] == "stones" and meta["context"] is True
    assert meta["policies"] == {n: f"ckpt_{n}" for n in STONES.policies}
    assert sorted(p.name for p in res.iterdir() if p.suffix == ".json") == [
        "lookup_stand_context_stones.json"]
    doc = json.loads((res / "lookup_stand_context_stones.json").read_text())
    want = np.full((5, 4), np.nan)
    want[:4, 3] = [0.085, 0.055, 0.105, 0.115]
    got = np.array([[np.nan if v is None else v for v in r] for r in doc["matrix_m"]])
    np.testing.assert_allclose(got, want)
    assert set(doc["tables"]) == {"stones"}
    assert doc["meta"]["policies"]["stones"] == meta["policies"]
    # into jumps, the stones policy is a source (slot 4) and the stones table stays
    assert sweep_cli.main(argv[:-1] + ["jumps"]) == 0
    doc = json.loads((res / "lookup_stand_context_stones.json").read_text())
    assert set(doc["tables"]) == {"stones", "jumps"}
    m = lookup.load_lookup("stand_context_stones", res, STONES)
    assert np.isfinite(m[4, 0]) and np.isnan(m[1, 0]) and np.isfinite(m[:4, 3]).all()
    assert lookup.context_lookup_missing("stand", res, STONES) == ["gaps", "stairs"]


def test_cli_papers_context_sweep_is_as_before(fake_context, tmp_path):
    out, res = tmp_path / "sweeps", tmp_path / "lookup"
    argv = ["--context", "--points", "30", "--batch", "6", "--tracks", "1000", "--out", str(out),
            "--results", str(res), "--targets", "gaps"]
    assert sweep_cli.main(argv) == 0
    assert fake_context[0] == (sweep.context_plan("gaps", 1000)[0], PAPER)
    assert fake_context[0][0][:3] == [["gaps", "jumps"], ["jumps", "gaps"], ["stairs", "gaps"]]
    meta = json.loads((out / "stand_context/gaps/meta.json").read_text())
    assert "lineup" not in meta and list(meta["policies"]) == list(PAPER.policies)
    doc = json.loads((res / "lookup_stand_context.json").read_text())
    assert np.array(doc["matrix_m"], dtype=float).shape == (4, 3)
    assert list(doc["best_m"])[:4] == ["walk->jumps", "jumps->jumps", "gaps->jumps",
                                       "stairs->jumps"]


def test_replays_of_two_lineups_keep_each_others_label_noise_rows(tmp_path, monkeypatch):
    """label_noise.json has a row per target; a stones replay of jumps adds a row naming its
    line-up beside the paper's jumps row, and a paper replay replaces only the paper's row."""
    monkeypatch.setattr(sweep_products, "load_data", lambda path: {})
    monkeypatch.setattr(sweep_products.sweep_lib, "replay_labels",
                        lambda data, n, *a, **kw: {"target": "jumps", "agree_pct": float(n)})
    (tmp_path / "jumps.npz").touch()
    a = types.SimpleNamespace(targets=["jumps"], replay=1, replay_batch=3, runs="runs",
                              stand_in=None, backend="mujoco", seed=0)
    dst = tmp_path / "label_noise.json"

    def rows():
        return sorted((r["target"], r.get("lineup", ""), r["agree_pct"])
                      for r in json.loads(dst.read_text()))

    assert sweep_products.replay(a, tmp_path, tmp_path) == 0
    assert "lineup" not in json.loads(dst.read_text())[0]  # the paper's rows as before
    a.replay = 2
    sweep_products.replay(a, tmp_path, tmp_path, STONES)
    assert rows() == [("jumps", "", 1.0), ("jumps", "stones", 2.0)]
    a.replay = 3
    sweep_products.replay(a, tmp_path, tmp_path)
    assert rows() == [("jumps", "", 3.0), ("jumps", "stones", 2.0)]
