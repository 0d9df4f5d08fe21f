"""Parameter presets and the promised configuration errors."""

import subprocess
import sys
import textwrap

import pytest

from vswrist_gym.params import ParamsError, load_params


def write(tmp_path, text, name="custom.yaml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def test_presets_hold_the_seed_values():
    paper, knm = load_params("paper"), load_params("paper_knm")
    assert load_params() is paper
    assert paper.spring.K == 0.004 and paper.spring.delta0 == 0.32
    assert knm.spring.K == 4.0 and knm.spring.delta0 == 0.32
    assert paper.geometry.d == 0.049 and knm.geometry == paper.geometry
    assert paper.inertia.hand_mass == 0.3 and paper.inertia.hand_offset == 0.1


def test_params_are_frozen():
    with pytest.raises(Exception):
        load_params().spring.K = 1.0


def test_file_inheriting_from_a_preset(tmp_path):
    p = load_params(write(tmp_path, """
        base: paper
        spring:
          K: {value: 0.01, unit: N*m, reason: test}
    """))
    assert p.spring.K == 0.01 and p.spring.delta0 == 0.32


@pytest.mark.parametrize("body, message", [
    ("spring:\n  stiffnes: {value: 1, unit: N*m}\n", "unknown parameter 'spring.stiffnes'"),
    ("sprung:\n  K: {value: 1, unit: N*m}\n", "unknown section 'sprung'"),
    ("spring:\n  K: {value: 'soft', unit: N*m}\n", "'spring.K' must be a number in (0, inf) N*m"),
    ("spring:\n  delta0: {value: 0.0, unit: rad}\n", "'spring.delta0' = 0 is outside the allowed range (0, inf) rad"),
    ("spring:\n  delta0: {value: -0.3, unit: rad}\n", "'spring.delta0' = -0.3 is outside the allowed range"),
    ("inertia:\n  hand_mass: {value: -0.3, unit: kg}\n", "'inertia.hand_mass' = -0.3 is outside the allowed range [0, inf) kg"),
    ("inertia:\n  link_mass: {value: [0.01, 0.01], unit: kg}\n", "'inertia.link_mass' must be a list of 3 numbers"),
    ("spring:\n  K: {value: 4, unit: N*mm}\n", "'spring.K' must be given in N*m, the file says 'N*mm'"),
    ("spring:\n  K: 4\n", "'spring.K' must be a mapping with 'value' and 'unit'"),
    ("range_of_motion:\n  fe_min: {value: 1.0, unit: rad}\n", "'range_of_motion.fe_min' must be below"),
    ("spring: [1, 2\n", "not valid YAML"),
])
def test_config_errors_name_the_field(tmp_path, body, message):
    path = write(tmp_path, "base: paper\n" + body)
    with pytest.raises(ParamsError) as err:
        load_params(path)
    assert message in str(err.value)


def test_unknown_preset_and_missing_values(tmp_path):
    with pytest.raises(ParamsError, match="unknown parameter preset or file 'papr'; presets: paper, paper_knm"):
        load_params("papr")
    with pytest.raises(ParamsError, match="missing parameter"):
        load_params(write(tmp_path, "spring:\n  K: {value: 1, unit: N*m}\n"))


def test_replace_validates():
    p = load_params()
    assert p.replace(spring={"K": 0.02}).spring.K == 0.02
    with pytest.raises(ParamsError, match="'motor.torque_limit' = -1 is outside"):
        p.replace(motor={"torque_limit": -1})
    with pytest.raises(ParamsError, match="unknown parameter 'motor.torq'"):
        p.replace(motor={"torq": 1})


def test_vswrist_info_runs_and_self_checks():
    out = subprocess.run([sys.executable, "-m", "vswrist_gym.cli", "info"], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    assert "Kinematics self-check" in out.stdout and "(ok)" in out.stdout
    assert "positive stiffens" in out.stdout


def test_cli_rejects_unknown_command():
    out = subprocess.run([sys.executable, "-m", "vswrist_gym.cli", "fly"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "unknown command 'fly'" in out.stderr


def test_cli_version_is_the_installed_distributions():
    from importlib.metadata import version

    out = subprocess.run([sys.executable, "-m", "vswrist_gym.cli", "--version"], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == f"vswrist-gym {version('vswrist-gym')}"  # pyproject.toml's, via the metadata
