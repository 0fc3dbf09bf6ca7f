from pathlib import Path

import pytest

from qpatrol.config import (
    ALIASES,
    KEYS,
    ConfigError,
    defaults,
    from_flat,
    from_mapping,
    load_config,
)

REQUIRED = [
    "map",
    "agents",
    "runs",
    "seed",
    "steps",
    "max_episode_steps",
    "learning.gamma",
    "learning.multiplier",
    "learning.q_init.north",
    "learning.q_init.east",
    "learning.q_init.south",
    "learning.q_init.west",
    "learning.epsilon",
    "learning.state_space",
    "reward.dot_value",
    "reward.big_dot_value",
    "reward.incremental_value",
    "reward.idle_horizon",
    "reward.lambda",
    "team.communication",
    "team.avoid_collisions",
    "battery.enabled",
    "battery.capacity",
    "battery.margin",
    "battery.charge_steps",
    "record.transitions",
    "record.watch",
]


def test_every_issue_key_exists_with_paper_defaults():
    # team.avoid_collisions is read as team.interaction (an alias, below)
    assert set(REQUIRED) <= set(KEYS) | set(ALIASES)
    d = defaults()
    assert d["learning.gamma"] == 0.1
    assert d["learning.multiplier"] == 100
    assert [d[f"learning.q_init.{k}"] for k in ("north", "west", "east", "south")] == [3, 2, 2, 1]
    assert d["learning.epsilon"] == 0.0


def test_nested_yaml_and_overrides(tmp_path: Path):
    p = tmp_path / "c.yaml"
    p.write_text("agents: 2\nlearning:\n  gamma: 0.5\nteam:\n  communication: off\nbattery: off\n")
    cfg = load_config(p, ["learning.gamma=0.7", "record.watch=[13, 4, 13]", "map=map_b"])
    assert cfg["agents"] == 2
    assert cfg["learning.gamma"] == 0.7
    assert cfg["team.communication"] is False
    assert cfg["battery.enabled"] is False
    assert cfg["record.watch"] == [4, 13]
    assert cfg["map"] == "map_b"
    # the resolved YAML round-trips
    again = tmp_path / "again.yaml"
    again.write_text(cfg.to_yaml())
    assert load_config(again).values == cfg.values
    assert load_config(again).digest() == cfg.digest()


@pytest.mark.parametrize(
    "flat, words",
    [
        (
            {"learning.gamma": 1.5},
            "learning.gamma: got 1.5 (out of range); allowed: a number in [0, 1]",
        ),
        ({"agents": 0}, "agents: got 0 (out of range); allowed: an integer in [1, 1024]"),
        ({"agents": 2.5}, "agents: got 2.5; allowed: an integer"),
        ({"agents": True}, "agents: got True"),
        ({"learning.gama": 0.1}, "unknown config key 'learning.gama'"),
        ({"team.communication": "maybe"}, "team.communication: got 'maybe'"),
        ({"learning.state_space": "grid"}, "allowed: one of cell_heading, cell"),
        ({"record.watch": [-1]}, "record.watch"),
        ({"learning.multiplier": 0}, "learning.multiplier: got 0 (out of range)"),
    ],
)
def test_bad_values_name_the_key(flat, words):
    with pytest.raises(ConfigError) as e:
        from_flat(flat)
    assert words in str(e.value)
    assert "\n" not in str(e.value)


def test_unknown_nested_key_and_bad_group():
    with pytest.raises(ConfigError, match="unknown config key 'learning.alpha'"):
        from_mapping({"learning": {"alpha": 0.5}})
    with pytest.raises(ConfigError, match="learning: expected a mapping"):
        from_mapping({"learning": 3})


def test_file_errors(tmp_path: Path):
    with pytest.raises(ConfigError, match="no such config file"):
        load_config(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("agents: [1,\n")
    with pytest.raises(ConfigError, match=r"bad.yaml:\d+:\d+"):
        load_config(bad)
    with pytest.raises(ConfigError, match="expected KEY=VALUE"):
        load_config(_ok(tmp_path), ["gamma"])


def _ok(tmp_path: Path) -> Path:
    p = tmp_path / "ok.yaml"
    p.write_text("agents: 1\n")
    return p


def test_set_reads_exponent_numbers(tmp_path: Path):
    cfg = load_config(_ok(tmp_path), ["learning.epsilon=1e-3", "steps=2e3"])
    assert cfg["learning.epsilon"] == 0.001 and cfg["steps"] == 2000


def test_avoid_collisions_is_read_as_the_interaction(tmp_path: Path):
    """The old switch sets ``team.interaction``: on is exclusive, off is none; reading it
    back tells whether the interaction is exclusive; given with a different
    ``team.interaction`` in one file it is refused, and a later ``--set`` replaces either."""
    assert defaults()["team.interaction"] == "exclusive"
    assert from_flat({"team.avoid_collisions": False})["team.interaction"] == "none"
    assert from_flat({"team.avoid_collisions": "on"})["team.interaction"] == "exclusive"
    assert from_flat({"team.interaction": "interference"})["team.avoid_collisions"] is False
    assert "avoid_collisions" not in from_flat({"team.avoid_collisions": False}).to_yaml()
    p = tmp_path / "c.yaml"
    p.write_text("team:\n  avoid_collisions: off\n")
    assert load_config(p)["team.interaction"] == "none"
    cfg = load_config(p, ["team.interaction=interference"])
    assert cfg["team.interaction"] == "interference"
    assert load_config(p, ["team.avoid_collisions=on"])["team.interaction"] == "exclusive"
    p.write_text("team:\n  avoid_collisions: off\n  interaction: exclusive\n")
    with pytest.raises(ConfigError, match="team.avoid_collisions: False means team.interaction"):
        load_config(p)
    p.write_text("team:\n  avoid_collisions: off\n  interaction: none\n")
    assert load_config(p)["team.interaction"] == "none"
    with pytest.raises(ConfigError, match="team.avoid_collisions: got 'sometimes'"):
        from_flat({"team.avoid_collisions": "sometimes"})


def test_interference_keys_are_checked_together():
    assert from_flat({"team.interference_steps": 9, "team.interference_cooldown": 10})
    with pytest.raises(ConfigError, match="team.interference_cooldown: got 3 .* more than"):
        from_flat({"team.interference_steps": 3, "team.interference_cooldown": 3})
    with pytest.raises(ConfigError, match="team.interaction: got 'pass'"):
        from_flat({"team.interaction": "pass"})


def test_a_config_read_again_is_the_files_as_it_is_now(tmp_path: Path, monkeypatch):
    """load_config parses a text once per folder (a figure reads a sweep's points several
    times): the same file again gives an equal config, not parsed again; a changed file
    is read as changed; the same text in another folder takes its relative map from
    there; an error is raised every time; and a caller changing its config's values
    does not change another's."""
    import qpatrol.config as config

    parsed = []
    parse = config._parse_config
    monkeypatch.setattr(config, "_parse_config", lambda p, t: parsed.append(p) or parse(p, t))
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir(), b.mkdir()
    for d in (a, b):
        (d / "c.yaml").write_text("agents: 2\nmap: floor.txt\n")
    first = load_config(a / "c.yaml")
    again = load_config(a / "c.yaml")
    assert again.values == first.values and again["map"] == str(a / "floor.txt")
    assert len(parsed) == 1
    first.values["agents"] = 99
    first.values["record.watch"].append(7)
    assert load_config(a / "c.yaml")["agents"] == 2
    assert load_config(a / "c.yaml")["record.watch"] == again["record.watch"] != [7]
    assert load_config(b / "c.yaml")["map"] == str(b / "floor.txt") and len(parsed) == 2
    (a / "c.yaml").write_text("agents: 3\nmap: floor.txt\n")
    assert load_config(a / "c.yaml")["agents"] == 3 and len(parsed) == 3
    (a / "c.yaml").write_text("agents: 0\n")
    for _ in range(2):
        with pytest.raises(ConfigError, match="agents"):
            load_config(a / "c.yaml")
    assert len(parsed) == 5
