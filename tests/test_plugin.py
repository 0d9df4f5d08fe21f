"""The springs and motors as MuJoCo engine plugins: the exported MJCF file, loaded fresh with plain MuJoCo,
against ``WristSim`` (same commands, same steps), the static stiffness against the analytic model, the
wrist mounted on another arm, per-mjData state under threads, and the errors a user meets."""

from __future__ import annotations

import copy
import importlib.util
import math
import os
import re
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from vswrist_gym.kinematics import LEG_NAMES, WristKinematics  # noqa: E402
from vswrist_gym.model import native  # noqa: E402
from vswrist_gym.model.builder import export_xml  # noqa: E402
from vswrist_gym.model.export import export, main as export_main  # noqa: E402
from vswrist_gym.params import load_params  # noqa: E402
from vswrist_gym.sim import WristSim  # noqa: E402
from vswrist_gym.stiffness import coupler_stiffness, lambda_range, motor_references  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
_JOINT, _BODY, _ACT = mujoco.mjtObj.mjOBJ_JOINT, mujoco.mjtObj.mjOBJ_BODY, mujoco.mjtObj.mjOBJ_ACTUATOR

try:
    native.load_plugin()
except RuntimeError as exc:  # no C compiler: nothing here can run
    pytest.skip(f"the compiled plugin is unavailable: {exc}", allow_module_level=True)


def _exported(tmp_path, params) -> tuple[mujoco.MjModel, Path]:
    out, _ = export(params, tmp_path / "wrist.xml")
    return mujoco.MjModel.from_xml_path(str(out)), out


def _name_map(src: mujoco.MjModel, dst: mujoco.MjModel):
    """((qpos src, qpos dst), (dof src, dof dst), actuator dst): index arrays pairing ``src``'s entries with
    ``dst``'s, joints and actuators matched by name (the exported tree nests the legs under ``base``)."""
    q_src, q_dst, v_src, v_dst = [], [], [], []
    for j in range(src.njnt):
        k = mujoco.mj_name2id(dst, _JOINT, mujoco.mj_id2name(src, _JOINT, j))
        assert k >= 0 and src.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE
        q_src.append(src.jnt_qposadr[j]), q_dst.append(dst.jnt_qposadr[k])
        v_src.append(src.jnt_dofadr[j]), v_dst.append(dst.jnt_dofadr[k])
    a_dst = [mujoco.mj_name2id(dst, _ACT, mujoco.mj_id2name(src, _ACT, a)) for a in range(src.nu)]
    return (np.array(q_src), np.array(q_dst)), (np.array(v_src), np.array(v_dst)), np.array(a_dst)


@pytest.mark.parametrize("preset", ["paper", "paper_knm"])
def test_exported_model_reproduces_wristsim_trajectories(tmp_path, preset):
    """Random references (motors saturating), a wrench on the hand and gravity, for 0.5 s: the file's model,
    loaded by plain MuJoCo, follows WristSim's states (and its loop-closure monitor) to 1e-9."""
    m, _ = _exported(tmp_path, preset)
    d = mujoco.MjData(m)
    sim = WristSim(preset, backend="c")
    (qs, qd), (vs, vd), ad = _name_map(sim.model, m)
    assert m.nu == sim.model.nu == 4 and m.nplugin == 5
    u = np.array([0.3, -0.2])
    sim.reset(u=u, ps=0.4, lam=0.6 * lambda_range(u, sim.params)[1])
    mujoco.mj_resetData(m, d)
    d.qpos[qd], d.qvel[vd] = sim.data.qpos[qs], sim.data.qvel[vs]
    d.ctrl[ad], d.act[m.actuator_actadr[ad]] = sim.data.ctrl, sim.data.act
    hand = mujoco.mj_name2id(m, _BODY, "hand")
    peak_adr = m.plugin_stateadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_PLUGIN, "closure")]
    rng = np.random.default_rng(7)
    worst = 0.0
    moved = 0.0
    for k in range(25):
        if k % 5 == 0:
            theta = sim.motor_angles() + rng.uniform(-0.4, 0.4, 4)
            sim.set_motor_references(theta)
            d.ctrl[ad] = theta
        if k == 10:
            sim.apply_wrench(force=(0.0, 0.0, -2.0), torque=(0.0, 0.02, 0.0))
            d.xfrc_applied[hand] = [0.0, 0.0, -2.0, 0.0, 0.02, 0.0]
        sim.step(0.02)
        d.plugin_state[peak_adr] = 0.0  # as WristSim.step restarts its peak
        mujoco.mj_step(m, d, 20)
        worst = max(worst, float(np.abs(d.qpos[qd] - sim.data.qpos[qs]).max()),
                    float(np.abs(d.qvel[vd] - sim.data.qvel[vs]).max()),
                    float(np.abs(d.act[m.actuator_actadr[ad]] - sim.data.act).max()))
        # the monitor differences positions ~0.05 m apart: rounding-level state differences show at ~1e-12
        assert d.plugin_state[peak_adr] == pytest.approx(sim._closure_peak[0], rel=0, abs=1e-9)
        moved = max(moved, float(np.abs(sim.data.qpos[qs] - sim.model.qpos0[qs]).max()))
    print(f"largest state difference {worst:.2e}")
    assert worst < 1e-9
    assert moved > 0.2  # the comparison spans real motion


class ExportedWrist:
    """The interface ``test_sim.measure_stiffness`` drives, on a model loaded from an exported file with no
    vswrist_gym code in its physics: the state is set from the analytic kinematics and stiffness model."""

    def __init__(self, path: Path, params):
        self.params = load_params(params)
        self.kin = WristKinematics(self.params)
        self.m = mujoco.MjModel.from_xml_path(str(path))
        self.d = mujoco.MjData(self.m)
        jid = lambda n: mujoco.mj_name2id(self.m, _JOINT, n)  # noqa: E731
        self.legs = self.m.jnt_qposadr[[jid(f"leg{n}_q{i}") for n in LEG_NAMES for i in range(1, 5)]]
        self.motors = self.m.jnt_qposadr[[jid(f"motor_{n}") for n in LEG_NAMES] + [jid("ps")]]
        self.coupler = mujoco.mj_name2id(self.m, _BODY, "coupler")
        self.hand = mujoco.mj_name2id(self.m, _BODY, "hand")
        self.n = int(round(0.1 / self.m.opt.timestep))

    def reset(self, u, lam):
        m, d = self.m, self.d
        mujoco.mj_resetDataKeyframe(m, d, 0)
        theta = np.append(motor_references(np.asarray(u, float), lam, self.params), 0.0)
        d.qpos[self.legs] = self.kin.joint_angles(np.asarray(u, float))
        d.qpos[self.motors] = theta
        d.ctrl[:4] = theta
        d.act[:4] = theta
        mujoco.mj_forward(m, d)

    def apply_wrench(self, torque):
        self.d.xfrc_applied[self.hand, 3:] = torque

    def step(self, duration_s):
        assert duration_s == 0.1
        mujoco.mj_step(self.m, self.d, self.n)
        mujoco.mj_forward(self.m, self.d)

    def posture(self):
        R = self.d.xmat[self.coupler]
        return np.array([math.asin(max(-1.0, min(1.0, -R[6]))), math.atan2(R[3], R[0])])

    def posture_rate(self):  # the settle criterion only needs to vanish at rest
        return self.d.cvel[self.coupler, :3].copy()


@pytest.mark.parametrize("preset, u, frac", [("paper", (0.5, 0.4), 0.9), ("paper_knm", (-0.6, -0.5), -0.8)])
def test_exported_model_passes_the_static_stiffness_validation(tmp_path, preset, u, frac):
    """``tests/test_sim.py``'s check on the exported file: the measured static stiffness is within 3 % of the
    complete analytic one, and the paper's formula (no load term) is measurably further off."""
    from test_sim import measure_stiffness

    p0 = load_params(preset)
    lo, hi = lambda_range(u, p0)
    lam = frac * (hi if frac > 0 else -lo)
    S_ref = coupler_stiffness(u, lam, p0)
    c = 0.3 * np.sqrt(np.linalg.eigvalsh(S_ref).min() * 6e-3)  # near-critical damping: settles quickly
    params = p0.replace(environment={"gravity": [0.0, 0.0, 0.0]}, damping={"leg_joint": c})
    _, path = _exported(tmp_path, params)
    S = measure_stiffness(ExportedWrist(path, params), u, lam)
    err = np.linalg.norm(S - S_ref) / np.linalg.norm(S_ref)
    err_paper = np.linalg.norm(coupler_stiffness(u, lam, p0, include_load_term=False) - S) / np.linalg.norm(S)
    assert err < 0.03, f"{preset} u={u} lam={frac}: {err:.3%} from the complete analytic stiffness"
    assert err_paper > 3 * err


def _run(code: str, env_extra: dict[str, str], cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, **env_extra)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=cwd,
                          timeout=120)


def _entry_point_site(tmp_path) -> Path:
    """A directory that, on sys.path, declares pyproject.toml's ``mujoco.plugins`` entry point the way an
    installed vswrist-gym does (the shared test environment may not be reinstalled)."""
    site = tmp_path / "site"
    dist = site / "vswrist_ep_probe-0.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: vswrist-ep-probe\nVersion: 0\n")
    entry = re.search(r'\[project\.entry-points\."mujoco\.plugins"\]\n(\w+ = "[\w.:]+")',
                      (ROOT / "pyproject.toml").read_text()).group(1)
    (dist / "entry_points.txt").write_text("[mujoco.plugins]\n" + entry.replace('"', "") + "\n")
    return site


def test_exported_file_without_the_plugin_library_fails_clearly(tmp_path):
    _, path = _exported(tmp_path, "paper")
    # VSWRIST_NATIVE=0 also keeps vswrist-gym's mujoco.plugins entry point from loading the library
    res = _run(f"import mujoco; mujoco.MjModel.from_xml_path({str(path)!r})", {"VSWRIST_NATIVE": "0"}, tmp_path)
    assert res.returncode != 0
    assert "vswrist.drive" in res.stderr and "not found" in res.stderr, res.stderr


def test_plugin_library_loads_in_a_plain_process_and_through_the_entry_point(tmp_path):
    """A program with no vswrist_gym import loads the file after ``mj_loadPluginLibrary``; and ``import mujoco``
    alone does it when a distribution declares the ``mujoco.plugins`` entry point (as pyproject.toml does)."""
    _, path = _exported(tmp_path, "paper")
    library = native.load_plugin()
    probe = (f"import mujoco; m = mujoco.MjModel.from_xml_path({str(path)!r}); d = mujoco.MjData(m); "
             "mujoco.mj_step(m, d, 10); print(m.nplugin, 'vswrist_gym' in __import__('sys').modules)")
    # VSWRIST_NATIVE=0: an installed vswrist-gym's entry point stays off, so only mj_loadPluginLibrary loads it
    res = _run(f"import mujoco; mujoco.mj_loadPluginLibrary({str(library)!r}); " + probe.split("; ", 1)[1],
               {"VSWRIST_NATIVE": "0"}, tmp_path)
    assert res.returncode == 0 and res.stdout.split()[0] == "5", res.stderr
    site = _entry_point_site(tmp_path)
    env = {"PYTHONPATH": os.pathsep.join([str(site), str(ROOT)])}
    res = _run(probe, env, tmp_path)
    assert res.returncode == 0 and res.stdout.split() == ["5", "True"], res.stderr
    # the package's own first `import mujoco` runs the entry point halfway through importing the package: it
    # must load the library there too (an entry point that imports the half-imported builder fails, and
    # MuJoCo's loader turns that into a warning: the file then does not load)
    res = _run("import vswrist_gym.model.native\n" + probe, env, tmp_path)
    assert res.returncode == 0 and res.stdout.split() == ["5", "True"], res.stderr


@pytest.mark.skipif(shutil.which("xvfb-run") is None, reason="needs xvfb-run for a display")
def test_mujoco_viewer_opens_the_exported_file_with_only_import_mujoco(tmp_path):
    """MuJoCo's own viewer, in a process that imports nothing of vswrist_gym itself: the entry point loads the
    plugin, the file loads, and the passive viewer draws 50 frames of it stepping (under Xvfb)."""
    _, path = _exported(tmp_path, "paper_knm")
    site = _entry_point_site(tmp_path)
    code = (f"import mujoco, mujoco.viewer; m = mujoco.MjModel.from_xml_path({str(path)!r}); d = mujoco.MjData(m)\n"
            "with mujoco.viewer.launch_passive(m, d) as v:\n"
            "    for _ in range(50):\n"
            "        mujoco.mj_step(m, d, 20); v.sync()\n"
            # os._exit: MuJoCo's GL teardown at interpreter exit can crash under Xvfb, with or without the
            # plugin (the same file with its plugins stripped does too); the frames are what is tested
            "print('frames drawn', m.nplugin, flush=True); import os; os._exit(0)\n")
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM", "DISPLAY")}
    env["PYTHONPATH"] = os.pathsep.join([str(site), str(ROOT)])
    res = subprocess.run(["xvfb-run", "-a", "-s", "-screen 0 1920x1080x24", sys.executable, "-c", code],
                         capture_output=True, text=True, env=env, cwd=tmp_path, timeout=180)
    assert res.returncode == 0 and "frames drawn 5" in res.stdout, res.stderr[-2000:]


def test_mounted_on_an_arm_the_springs_hold_the_hand(tmp_path):
    """``examples/attach_arm.py``: the wrist attached to a two-link arm with ``MjSpec`` keeps its posture while
    the arm swings (the preloaded springs hold the 300 g hand), where the same wrist without its plugins
    (MuJoCo sees no springs and frozen setpoints) folds under the hand's weight."""
    spec = importlib.util.spec_from_file_location("attach_arm", ROOT / "examples" / "attach_arm.py")
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    _, path = _exported(tmp_path, "paper_knm")
    held = example.run(str(path))
    assert held["model"].nplugin == 5 and held["model"].nu == 6
    assert abs(held["deflection"]).min() > 0.3  # the preload is on
    assert held["drift"] < 0.1
    bare = tmp_path / "bare.xml"
    text = re.sub(r"\s*<extension>.*?</extension>", "", path.read_text(), flags=re.S)
    bare.write_text(re.sub(r'\s*<plugin instance="\w+"/>', "", text))
    assert example.run(str(bare))["drift"] > 0.5


def test_state_is_per_mjdata_threads_and_copies_step_as_in_sequence(tmp_path):
    """All mutable plugin state lives in each mjData: four mjData stepped at once on four threads (mj_step
    releases the GIL) and a copy made mid-run end exactly where the same runs done one after another end."""
    m, _ = _exported(tmp_path, "paper_knm")
    stiff = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, "home_stiff")

    def make(i):
        d = mujoco.MjData(m)
        mujoco.mj_resetDataKeyframe(m, d, stiff)
        d.ctrl[:4] += 0.1 * (i + 1) * np.array([1.0, -1.0, 0.5, 2.0])
        return d

    def run(d):
        for _ in range(10):
            mujoco.mj_step(m, d, 50)

    sequential = [make(i) for i in range(4)]
    for d in sequential:
        run(d)
    parallel = [make(i) for i in range(4)]
    threads = [threading.Thread(target=run, args=(d,)) for d in parallel]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for a, b in zip(sequential, parallel):
        np.testing.assert_array_equal(a.qpos, b.qpos)
        np.testing.assert_array_equal(a.plugin_state, b.plugin_state)
    assert np.abs(sequential[0].qpos - sequential[3].qpos).max() > 1e-3  # the runs differ
    d = make(0)
    mujoco.mj_step(m, d, 100)
    twin = copy.copy(d)
    del d  # the copy owns its own plugin data
    mujoco.mj_step(m, twin, 400)
    np.testing.assert_array_equal(twin.qpos, sequential[0].qpos)


def test_export_command_errors_are_one_line(tmp_path, capsys):
    assert export_main(["--params", "no_such_preset", "--out", str(tmp_path / "w.xml")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--params" in err and "no_such_preset" in err
    assert export_main(["--params", "paper", "--out", str(tmp_path / "missing" / "w.xml")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--out" in err
    assert export_main(["--out", str(tmp_path / "w.xml")]) == 0
    out = capsys.readouterr().out
    assert str(native.load_plugin()) in out and (tmp_path / "w.xml").is_file()


def test_bad_plugin_configuration_is_named_by_the_compiler():
    """A hand-edited file with a broken instance gets MuJoCo's compiler error naming the instance and key."""
    xml = re.sub(r'<config key="K" value="[^"]*"/>', '<config key="K" value="-1"/>', export_xml("paper"), count=1)
    with pytest.raises(ValueError, match=r"instance 'drive_A'.*K \(N m\) and delta0"):
        mujoco.MjModel.from_xml_string(xml)
    xml = export_xml("paper").replace('<plugin instance="drive_ps"/>', "", 1)
    with pytest.raises(ValueError, match=r"drive_ps.*no body references it"):
        mujoco.MjModel.from_xml_string(xml)
    xml = re.sub(r'(<instance name="drive_A">.*?)<config key="time_constant".*?(</instance>)', r"\1\2",
                 export_xml("paper"), count=1, flags=re.S)
    with pytest.raises(ValueError, match=r"drive_A.*actuator 'motor_A' has dyntype=\"user\""):
        mujoco.MjModel.from_xml_string(xml)
    xml = re.sub(r"<equality>.*?</equality>", "", export_xml("paper"), flags=re.S)
    with pytest.raises(ValueError, match=r"instance 'closure': no weld"):
        mujoco.MjModel.from_xml_string(xml)


def test_compiled_path_leaves_no_global_callback():
    """The fallback installs MuJoCo's process-global callbacks; a simulator on the compiled path removes them,
    and its springs still act (they are in the model)."""
    WristSim("paper_knm", backend="python")
    assert mujoco.get_mjcb_passive() is not None and mujoco.get_mjcb_act_dyn() is not None
    sim = WristSim("paper_knm")
    assert sim.backend == "c" and native.backend() == "c"
    assert mujoco.get_mjcb_passive() is None and mujoco.get_mjcb_act_dyn() is None
    sim.reset(lam=0.5 * lambda_range(np.zeros(2), sim.params)[1])
    sim.step(0.02)
    tau = -2.0 * sim.params.spring.K * np.sinh(sim.deflections() / sim.params.spring.delta0)
    q1 = sim.model.jnt_dofadr[[mujoco.mj_name2id(sim.model, _JOINT, f"leg{n}_q1") for n in LEG_NAMES]]
    mujoco.mj_forward(sim.model, sim.data)
    # the spring is the only passive force on q1 besides the joint damping
    damping = sim.model.dof_damping[q1] * sim.data.qvel[q1]
    np.testing.assert_allclose(sim.data.qfrc_passive[q1], tau - damping, rtol=1e-12, atol=1e-15)
    assert np.abs(tau).min() > 0.1


@pytest.mark.parametrize("variable, part", [("CC", "MuJoCo plugin"), ("CXX", "batched advance")])
def test_without_a_compiler_the_error_says_what_to_install(tmp_path, variable, part):
    """One physics path: where the plugin (C) or the batched advance (C++) cannot be compiled, making an env (or
    a batch) raises NativeBuildError naming the part, a compiler to install and the VSWRIST_NATIVE=0 reference,
    and the CLI says the same in one line; nothing falls back silently."""
    env = {variable: str(tmp_path / "no-such-compiler"), "VSWRIST_CACHE": str(tmp_path / "cache")}
    code = ("import gymnasium as gym, vswrist_gym\n"
            "from vswrist_gym.model.plugin_lib import NativeBuildError\n"
            "try:\n"
            "    gym.make_vec('VSWrist/Polish-v1', num_envs=2, vectorization_mode='vector_entry_point')\n"
            "except NativeBuildError as exc:\n"
            "    print('ERROR', exc)\n")
    res = _run(code, env, tmp_path)
    assert res.returncode == 0, res.stderr
    assert f"ERROR vswrist-gym compiles its {part}" in res.stdout
    assert "apt install gcc g++" in res.stdout and "VSWRIST_NATIVE=0" in res.stdout
    cli = subprocess.run([sys.executable, "-m", "vswrist_gym.cli", "evaluate", "--task", "Polish", "--agent",
                          "analytic:0", "--episodes", "2", "--seeds", "0", "--out", str(tmp_path / "out")],
                         capture_output=True, text=True, env=dict(os.environ, **env), cwd=tmp_path, timeout=120)
    assert cli.returncode != 0 and "Traceback" not in cli.stderr
    assert part in cli.stderr and "VSWRIST_NATIVE=0" in cli.stderr
