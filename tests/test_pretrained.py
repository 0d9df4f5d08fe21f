"""The policies shipped in vswrist_gym/pretrained/: they load through `--agent pretrained:<Task>[:<track>]`, their
files are what their cards say, and a replay gives the cards' per-episode returns.

Replay tolerance. A shipped policy is deterministic, and `vswrist evaluate` runs the episodes of a seed as the
worlds of one batch, so a replay with the card's seeds and episode count repeats the card's computation exactly:
on the machine and versions that wrote the card (`card.json` `replay.machine`) every return must match to 1e-6.
Elsewhere MuJoCo's and torch's floats round differently (the analytic baseline agrees across CPUs to 1e-13, the
policy's float32 network to about one float32 ulp, 1.2e-7 relative), and the closed loop can amplify a difference.
How much was measured when the card was written: the policy's actions multiplied by 1 + 1e-5 r (r uniform in
[-1, 1], about 100 float32 ulp, far more than two CPUs differ by) moved each return by at most
`replay.max_return_change`. On another machine a return must match within 10 times that change, or 1e-4 of the
return where that is larger (a task whose episodes the perturbation left unchanged still gets a bound that a
rounding difference cannot exceed, and a broken policy or statistics file, which moves returns by percent, still
fails). Success is compared on the card's machine only, since a threshold can flip on a rounding difference.
The machine is the versions and the CPU's name, family, model and SIMD flags (`ship_policies.cpu_id`): a
hypervisor can show two generations as the same "AMD EPYC", and a card replayed on one without AVX-512 moved a
stiffness-track return by 16.8 (Polish, within the cross-machine bound of 146). The shipped cards name the CPU only,
so they are held to the cross-machine bound on every machine until they are written again.
"""

from __future__ import annotations

import fnmatch
import json
import subprocess
import sys
import tomllib
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import vswrist_gym
from vswrist_gym import pretrained
from vswrist_gym.agents.hparams import ConfigError, track_of

SHIPPED = pretrained.shipped()
IDS = [f"{t}:{k}" for t, k in SHIPPED]
REPO = Path(__file__).resolve().parents[1]


def card_of(folder: Path) -> dict:
    return json.loads((folder / pretrained.CARD_FILE).read_text())


def test_something_ships():
    assert SHIPPED, "no policy in vswrist_gym/pretrained (python -m vswrist_gym.tools.ship_policies)"


# ------------------------------------------------------------------------------------------------ the spec


def _fake_root(tmp_path, items):
    for task, track in items:
        folder = tmp_path / pretrained.folder_name(task, track)
        folder.mkdir()
        (folder / "model.zip").write_bytes(b"")
        (folder / "config.yaml").write_text("")
    return tmp_path


def test_track_defaults_to_the_one_shipped_then_full(tmp_path):
    root = _fake_root(tmp_path, [("Polish", "full"), ("Polish", "stiffness"), ("Hammer", "stiffness")])
    assert pretrained.resolve("pretrained:Polish", root).name == "Polish_full"
    assert pretrained.resolve("pretrained:Polish:stiffness", root).name == "Polish_stiffness"
    assert pretrained.resolve("pretrained:Hammer", root).name == "Hammer_stiffness"
    assert pretrained.resolve("pretrained:VSWrist/Hammer-v0", root).name == "Hammer_stiffness"  # full ids too


@pytest.mark.parametrize("text, says", [
    ("pretrained:Hammer:full", "no full-track policy ships for Hammer"),
    ("pretrained:Drill", "no policy ships for Drill"),
    ("pretrained:Foo", "unknown task 'Foo'"),
    ("pretrained:Polish:half", "track must be one of full, stiffness"),
    ("pretrained:Polish:full:x", "write pretrained:<Task>[:<track>]"),
])
def test_unknown_task_or_track_lists_what_ships(tmp_path, text, says):
    root = _fake_root(tmp_path, [("Polish", "full"), ("Hammer", "stiffness")])
    with pytest.raises(ConfigError) as exc:
        pretrained.resolve(text, root)
    msg = str(exc.value)
    assert says in msg and "shipped: Hammer:stiffness, Polish:full" in msg and "\n" not in msg


@pytest.mark.parametrize("tool", ["evaluate", "video"])
def test_cli_error_is_one_line(tmp_path, tool):
    out = ["--out", str(tmp_path / ("x.mp4" if tool == "video" else "x"))]
    p = subprocess.run([sys.executable, "-m", "vswrist_gym.cli", tool, "--task", "Polish", "--agent",
                        "pretrained:Polish:half", *out], capture_output=True, text=True, cwd=REPO)
    assert p.returncode == 2
    assert p.stderr.count("\n") == 1 and "shipped: " + pretrained.describe(SHIPPED) in p.stderr


def test_only_the_final_model_ships():
    from vswrist_gym.agents.evaluate import AgentSpec

    task, track = next(iter(SHIPPED))
    with pytest.raises(ConfigError, match="final model only"):
        AgentSpec(f"pretrained:{task}:{track}", checkpoint="best")


# ------------------------------------------------------------------------------------------------ the files


@pytest.mark.parametrize("key", list(SHIPPED), ids=IDS)
def test_folder_is_a_trimmed_run_whose_card_matches(key):
    import hashlib

    from vswrist_gym.agents.runs import read_config

    task, track = key
    folder = SHIPPED[key]
    names = {p.name for p in folder.iterdir()}
    assert names == set(pretrained.RUN_FILES) | set(pretrained.CARD_FILES)  # no checkpoints, logs, curves
    card = card_of(folder)
    cfg, seed = read_config(folder)
    # a policy serves the id it was trained on, which is the task's newest or one kept registered beside it
    assert (card["task"], card["track"], card["env_id"]) == (task, track_of(cfg.env_kwargs), cfg.env_id)
    assert card["env_id"] in gym.registry and card["env_id"].split("/")[1].split("-v")[0] == task
    assert card["training_seed"] == seed and card["budget_steps"] == cfg.n_timesteps
    assert card["steps_trained"] >= card["budget_steps"]
    for name, entry in card["files"].items():
        data = (folder / name).read_bytes()
        assert len(data) == entry["bytes"] and hashlib.sha256(data).hexdigest() == entry["sha256"], name
    assert set(card["files"]) == set(pretrained.RUN_FILES)


@pytest.mark.parametrize("key", list(SHIPPED), ids=IDS)
def test_card_summary_follows_from_its_episodes(key):
    """The card's means and intervals are the protocol's statistics of the per-episode records it stores."""
    from vswrist_gym.agents.protocol import t_quantile

    ev = card_of(SHIPPED[key])["evaluation"]
    eps = ev["episodes"]
    assert sorted({e["seed"] for e in eps}) == ev["seeds"] and len(eps) == len(ev["seeds"]) * ev["episodes_per_seed"]
    per_seed = [np.mean([e["return"] for e in eps if e["seed"] == s]) for s in ev["seeds"]]
    half = t_quantile(0.975, len(per_seed) - 1) * np.std(per_seed, ddof=1) / np.sqrt(len(per_seed))
    r = ev["policy"]["return"]
    np.testing.assert_allclose([r["mean"], r["low"], r["high"]],
                               [np.mean(per_seed), np.mean(per_seed) - half, np.mean(per_seed) + half], rtol=1e-12)
    best = max(ev["constants"], key=lambda k: ev["constants"][k]["return"]["mean"])
    assert ev["best_constant"]["agent"] == best
    base = [np.mean([e["return"] for e in ev["best_constant_episodes"] if e["seed"] == s]) for s in ev["seeds"]]
    np.testing.assert_allclose(ev["difference_vs_best_constant"]["return"]["mean"],
                               np.mean(per_seed) - np.mean(base), rtol=1e-9)


def test_small_and_in_the_package_data():
    total = sum(p.stat().st_size for folder in SHIPPED.values() for p in folder.iterdir())
    assert total < 3 * 2**20, f"shipped policies take {total / 2**20:.2f} MiB"
    patterns = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["vswrist_gym"]
    for folder in SHIPPED.values():
        for p in folder.iterdir():
            rel = p.relative_to(REPO / "vswrist_gym").as_posix()
            assert any(fnmatch.fnmatch(rel, pat) for pat in patterns), f"{rel} is not package data"


# ------------------------------------------------------------------------------------------------ the replay


def replay(key, seeds):
    """The card's episodes of `seeds` through `--agent pretrained:...` and the protocol of `vswrist evaluate`."""
    from vswrist_gym.agents.evaluate import AgentSpec
    from vswrist_gym.agents.protocol import evaluate

    task, track = key
    card = card_of(SHIPPED[key])
    spec = AgentSpec(f"pretrained:{task}:{track}")
    spec.check_task(card["env_id"])
    records, _ = evaluate(card["env_id"], spec.make, seeds, card["evaluation"]["episodes_per_seed"],
                          env_kwargs=spec.env_kwargs)
    return card, records


def check_replay(card, records):
    from vswrist_gym.tools.ship_policies import machine

    rp = card["replay"]
    same_machine = rp["machine"] == machine()
    want = {(e["seed"], e["episode"]): e for e in card["evaluation"]["episodes"]}
    assert records
    for rec in records:
        ref = want[(rec["seed"], rec["episode"])]
        if same_machine:
            tol = 1e-6
            assert rec["success"] == ref["success"], (rec["seed"], rec["episode"])
        else:
            tol = max(rp["cross_machine_tolerance"]["margin"] * rp["max_return_change"],
                      rp["cross_machine_tolerance"]["relative_floor"] * abs(ref["return"]))
        assert abs(rec["return"] - ref["return"]) <= tol, \
            f"seed {rec['seed']} episode {rec['episode']}: {rec['return']} vs card {ref['return']} (tol {tol:.3g})"


@pytest.mark.parametrize("key", list(SHIPPED), ids=IDS)
def test_replay_first_seed_gives_the_card(key):
    card, records = replay(key, card_of(SHIPPED[key])["evaluation"]["seeds"][:1])
    check_replay(card, records)


@pytest.mark.slow
@pytest.mark.parametrize("key", list(SHIPPED), ids=IDS)
def test_replay_every_seed_gives_the_card(key):
    card, records = replay(key, card_of(SHIPPED[key])["evaluation"]["seeds"])
    check_replay(card, records)
    ret = [r["return"] for r in records]
    np.testing.assert_allclose(np.mean(ret), card["evaluation"]["policy"]["return"]["mean"],
                               rtol=card["replay"]["cross_machine_tolerance"]["relative_floor"],
                               atol=card["replay"]["cross_machine_tolerance"]["margin"]
                               * card["replay"]["max_return_change"])


# ------------------------------------------------------------------------------------------------ video and view


def _cross_tolerance(card, ret):
    rp = card["replay"]["cross_machine_tolerance"]
    return max(rp["margin"] * card["replay"]["max_return_change"], rp["relative_floor"] * abs(ret))


def test_video_and_view_drive_the_shipped_policy(tmp_path):
    """`vswrist video` and `vswrist view` run the policy one env at a time (the card's episodes ran as worlds of a
    batch, whose forward pass may round the last bits differently), on the card's first episode: its return
    within the cross-machine bound."""
    import re

    import gymnasium as gym

    from vswrist_gym.agents.evaluate import AgentSpec
    from vswrist_gym.tools.view import ViewerSession

    # Hammer's episodes are the shortest (60 steps): the cheapest video
    key = ("Hammer", "stiffness") if ("Hammer", "stiffness") in SHIPPED else next(iter(SHIPPED))
    card = card_of(SHIPPED[key])
    first = card["evaluation"]["episodes"][0]
    reset = 1_000_000 + 1000 * first["seed"] + first["episode"]
    agent_text = f"pretrained:{key[0]}:{key[1]}"
    out = tmp_path / "ep.mp4"
    p = subprocess.run([sys.executable, "-m", "vswrist_gym.cli", "video", "--task", card["env_id"], "--agent",
                        agent_text, "--seed", str(reset), "--width", "64", "--height", "48", "--out", str(out)],
                       capture_output=True, text=True, cwd=REPO)
    assert p.returncode == 0, p.stderr
    got = float(re.search(r"return (-?[\d.]+)", p.stdout)[1])
    assert abs(got - first["return"]) <= _cross_tolerance(card, first["return"]) + 0.005  # printed to 2 decimals

    spec = AgentSpec(agent_text)
    env = gym.make(card["env_id"], **spec.env_kwargs)
    lines = []
    session = ViewerSession(env, spec.make(env), seed=reset, speed=1e9, log=lines.append)

    class Handle:  # stands in for the viewer window: closes once the first episode has ended
        def is_running(self):
            return session.episodes == 0

        def sync(self):
            pass

        def close(self):
            pass

    session.run(lambda *a, **k: Handle())
    env.close()
    got = float(re.search(r"return (-?[\d.]+)", lines[0])[1])
    assert abs(got - first["return"]) <= _cross_tolerance(card, first["return"]) + 0.005


def test_replay_check_catches_wrong_statistics(tmp_path):
    """The comparison can fail: the same policy with its observation statistics shifted by one standard deviation
    (what a wrong or mixed-up vecnormalize.npz does) moves returns beyond even the cross-machine bound."""
    import shutil

    from vswrist_gym.agents.protocol import evaluate
    from vswrist_gym.agents.runs import TrainedAgent

    key = ("Hammer", "stiffness") if ("Hammer", "stiffness") in SHIPPED else next(iter(SHIPPED))
    folder = tmp_path / SHIPPED[key].name
    shutil.copytree(SHIPPED[key], folder)
    with np.load(folder / "vecnormalize.npz", allow_pickle=False) as a:
        arrays = {k: a[k] for k in a.files}
    arrays["obs_mean"] = arrays["obs_mean"] + np.sqrt(arrays["obs_var"])
    np.savez(folder / "vecnormalize.npz", **arrays)
    card = card_of(folder)
    agent = TrainedAgent(folder)
    records, _ = evaluate(card["env_id"], lambda env: agent, card["evaluation"]["seeds"][:1],
                          card["evaluation"]["episodes_per_seed"], env_kwargs=dict(agent.cfg.env_kwargs))
    card["replay"]["machine"] = "another machine"  # the looser, cross-machine bound
    with pytest.raises(AssertionError, match="tol"):
        check_replay(card, records)
