"""Scene validation: every kind of config error names the file, key path, value and what is allowed."""

import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from haptic_teleop.errors import ConfigError
from haptic_teleop.scene.load import find_scene, load_scene
from haptic_teleop.scene.schema import Scene
from haptic_teleop.typedconfig import describe

DEFAULT = find_scene("wall_contact")


def _write(tmp_path: Path, data: object, name: str = "s.yaml") -> Path:
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data) if not isinstance(data, str) else data)
    return p


def _base() -> dict:
    return yaml.safe_load(DEFAULT.read_text())


def test_default_scene_is_valid():
    s = load_scene(DEFAULT)
    assert s.config.scene.name == "wall_contact"
    assert s.config.network.forward.effects.delay is not None


@pytest.mark.parametrize(
    ("mutate", "key", "allowed"),
    [
        (lambda d: d["slave"]["wall"].update(stiffnes_n_per_m=1.0), "slave.wall.stiffnes_n_per_m", "unknown key"),
        (lambda d: d["master"].update(mass_kg="heavy"), "master.mass_kg", "a number"),
        (lambda d: d["master"].update(mass_kg=-1.0), "master.mass_kg", "> 0.0"),
        (lambda d: d["scene"].update(seed=1.5), "scene.seed", "an integer"),
        (
            lambda d: d["controllers"]["master"]["eba"].update(enabled="yes"),
            "controllers.master.eba.enabled",
            "true or false",
        ),
        (lambda d: d["operator"].update(profile="dance"), "operator.profile", "one of push"),
        (lambda d: d["simulation"].update(integrator="rk45"), "simulation.integrator", "one of Euler"),
        (lambda d: d["slave"]["wall"].update(stiffness_n_per_m=float("nan")), "slave.wall.stiffness_n_per_m", "finite"),
        (lambda d: d["controllers"]["slave"].update(law="force"), "controllers", "contradiction"),
        (
            lambda d: d["controllers"]["master"].update(force_limit_n=100.0),
            "<top level>",
            "exceeds master.force_limit_n",
        ),
        (lambda d: d["slave"]["wall"].update(position_m=-0.5), "slave", "beyond start_position_m"),
        (lambda d: d["operator"].update(trace_file="x.csv"), "operator", "only used with profile 'trace'"),
        (lambda d: d.update(scene=[1, 2]), "scene", "a mapping"),
    ],
)
def test_config_errors_name_key_and_allowed(tmp_path, mutate, key, allowed):
    data = _base()
    mutate(data)
    path = _write(tmp_path, data)
    with pytest.raises(ConfigError) as exc:
        load_scene(path)
    msg = str(exc.value)
    assert msg.startswith(str(path)), msg
    assert f"{key} =" in msg or f": {key}" in msg, msg
    assert allowed in msg, msg


def test_bad_yaml_and_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_scene(_write(tmp_path, "scene: {name: [unclosed"))
    with pytest.raises(ConfigError, match="existing scene YAML"):
        load_scene(tmp_path / "nope.yaml")
    with pytest.raises(ConfigError, match="a mapping of sections"):
        load_scene(_write(tmp_path, "- 1\n- 2\n"))


def test_overrides_and_seed():
    s = load_scene(DEFAULT, overrides=["slave.wall.stiffness_n_per_m=1e5", "scene.name=other"], seed=7)
    assert s.config.slave.wall.stiffness_n_per_m == 1e5
    assert s.config.scene.name == "other"
    assert s.config.scene.seed == 7
    with pytest.raises(ConfigError, match=r"KEY\.PATH=VALUE"):
        load_scene(DEFAULT, overrides=["slave.wall"])
    with pytest.raises(ConfigError, match="unknown key"):
        load_scene(DEFAULT, overrides=["slave.wal.position_m=0.1"])
    with pytest.raises(ConfigError, match="is a value, not a section"):
        load_scene(DEFAULT, overrides=["scene.name.first=1"])


def test_trace_file_errors(tmp_path):
    data = _base()
    data["operator"] = {"profile": "trace", "trace_file": "trace.csv"}
    path = _write(tmp_path, data)
    with pytest.raises(ConfigError, match="existing CSV"):
        load_scene(path)
    (tmp_path / "trace.csv").write_text("time_s,position_m\n0,0\n1,abc\n")
    with pytest.raises(ConfigError, match=r"trace\.csv:3"):
        load_scene(path)
    (tmp_path / "trace.csv").write_text("time_s,position_m\n0,0\n1,0.01\n2,0.02\n")
    s = load_scene(path)
    assert s.operator_trace == ((0.0, 1.0, 2.0), (0.0, 0.01, 0.02))


def test_cli_config_error_exit_code_2(tmp_path):
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "haptic_teleop.cli.main",
            "run",
            str(DEFAULT),
            "--out",
            str(tmp_path / "o"),
            "--set",
            "master.damping_n_s_per_m=-3",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2
    assert "master.damping_n_s_per_m = -3" in r.stderr
    assert "allowed" in r.stderr
    assert not (tmp_path / "o").exists()


def test_a_wall_too_stiff_for_the_step_is_rejected_with_the_substeps_it_needs():
    with pytest.raises(ConfigError) as exc:
        load_scene(find_scene("wall_contact"), overrides=["slave.wall.stiffness_n_per_m=1e7"])
    msg = str(exc.value)
    assert "slave.wall.stiffness_n_per_m" in msg and "simulation.substeps >= 3" in msg
    assert "{" not in msg  # names the keys, does not dump the scene
    # The remedy it names is accepted, and 1e6 N/m at 1 ms (omega h = 0.95) is fine as it is.
    load_scene(find_scene("wall_contact"), overrides=["slave.wall.stiffness_n_per_m=1e7", "simulation.substeps=3"])
    load_scene(find_scene("wall_contact"), overrides=["slave.wall.stiffness_n_per_m=1e6"])


def test_a_section_given_in_part_keeps_that_sections_own_defaults():
    """The slave controller's defaults (E0 0.5 J, limit 40 N) differ from ControllerConfig's; a scene
    or --set naming one slave key must not reset the others to the master's (a robot with E0 = 0
    never moves)."""
    s = load_scene(find_scene("varying_delay"), overrides=["controllers.slave.stiffness_n_per_m=300"])
    slave = s.config.controllers.slave
    assert slave.stiffness_n_per_m == 300.0
    assert slave.eba.initial_energy_j == 0.5 and slave.force_limit_n == 40.0
    s = load_scene(find_scene("varying_delay"), overrides=["controllers.slave.eba.enabled=false"])
    assert s.config.controllers.slave.eba.initial_energy_j == 0.5
    with pytest.raises(ConfigError, match="no_such_key"):
        load_scene(find_scene("varying_delay"), overrides=["controllers.slave.no_such_key=1"])


# --- property: any YAML document loads or raises ConfigError, nothing else ------------------------

_KNOWN = sorted({part for path, _, _ in describe(Scene) for part in path.split(".")})
_keys = st.one_of(st.sampled_from(_KNOWN), st.text(max_size=8), st.integers(-3, 3), st.booleans(), st.none())
_scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
    st.sampled_from(["push", "trace", "lowpass", "mujoco", "1e5", ".nan", "constant", "bernoulli", "fixed"]),
)
_values = st.recursive(
    _scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(_keys, inner, max_size=5)),
    max_leaves=25,
)


_EDGES = [10**400, -(10**400), 5e-324, -5e-324, 1e308, float("nan"), float("inf"), 2**63, -1, 0, "", [], {}, None]


def _mutated_default(draw_path: list[str], value: object) -> dict:
    data = _base()
    node = data
    for part in draw_path[:-1]:
        if not isinstance(node.get(part), dict):
            node[part] = {}
        node = node[part]
    node[draw_path[-1]] = value
    return data


_scene_paths = st.sampled_from([path.split(".") for path, _, _ in describe(Scene)])
_documents = st.one_of(
    _values.map(yaml.safe_dump),
    st.builds(_mutated_default, _scene_paths, _values).map(yaml.safe_dump),
    st.builds(_mutated_default, _scene_paths, st.sampled_from(_EDGES)).map(yaml.safe_dump),  # one leaf, an edge
    st.text(max_size=200),  # mostly not YAML at all
    st.binary(max_size=100).map(lambda b: b.decode("latin-1")),
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=_documents, raw=st.binary(max_size=40))
def test_any_document_loads_or_raises_config_error(tmp_path, text, raw):
    for content in (text.encode("utf-8", "surrogatepass"), raw):
        p = tmp_path / "fuzz.yaml"
        p.write_bytes(content)
        try:
            load_scene(p)
        except ConfigError as exc:
            assert str(exc).startswith(str(p))
