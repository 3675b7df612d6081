"""Wear-limit presets and policies: loading, clear errors, thresholds per wire type."""

from __future__ import annotations

from pathlib import Path

import pytest

from catenary.errors import UserError
from catenary.limits import (
    LimitPolicy,
    LimitRule,
    load_policies,
    parse_policies,
    policy_from_config,
    select_policy,
    thresholds,
)
from catenary.plugins import PluginRegistry
from catenary_wiretypes import PRESETS_PATH

PRESETS = load_policies(PRESETS_PATH)
WIRES = PluginRegistry().wire_types()


def test_every_preset_loads_with_source_and_rules() -> None:
    assert set(PRESETS) == {
        "db-ril-997",
        "china-maintenance-rules",
        "indian-railways-actm",
        "manufacturer-30pct",
    }
    for policy in PRESETS.values():
        assert policy.description
        assert policy.source
        assert policy.rules


def test_preset_rules_name_only_registered_wire_types() -> None:
    for policy in PRESETS.values():
        for rule in policy.rules:
            assert set(rule.wire_types) <= set(WIRES), (policy.name, rule)


@pytest.mark.parametrize("policy", sorted(PRESETS))
def test_every_preset_gives_thresholds_for_every_wire_type(policy: str) -> None:
    for wire in WIRES.values():
        for threshold in thresholds(wire, PRESETS[policy]):
            assert wire.min_residual_thickness_mm < threshold.residual_thickness_mm < wire.height_mm
            assert float(wire.residual_thickness_mm(threshold.wear_width_mm)) == pytest.approx(
                threshold.residual_thickness_mm, abs=1e-6
            )
            assert float(wire.worn_fraction(threshold.wear_width_mm)) == pytest.approx(
                threshold.worn_fraction, abs=1e-9
            )


def test_db_thresholds_for_ac120() -> None:
    found = thresholds(WIRES["AC-120"], PRESETS["db-ril-997"])
    by_criterion = {("fraction" if t.rule.worn_fraction else "thickness"): t for t in found}
    assert len(found) == 2  # 20 % for all, 10.0 mm for AC-120 only
    minimum = by_criterion["thickness"]
    assert minimum.residual_thickness_mm == 10.0
    assert minimum.level == "critical"
    loss = by_criterion["fraction"]
    assert loss.worn_fraction == 0.20
    assert loss.residual_thickness_mm == pytest.approx(10.14, abs=0.01)
    assert loss.wear_width_mm == pytest.approx(11.14, abs=0.01)
    assert loss.level == "urgent"
    assert all(t.scope == "local" for t in found)


@pytest.mark.parametrize(("wire", "minimum"), [("AC-80", 8.1), ("AC-100", 9.2), ("AC-120", 10.0)])
def test_db_minimum_thickness_per_wire_type(wire: str, minimum: float) -> None:
    found = thresholds(WIRES[wire], PRESETS["db-ril-997"])
    assert [t.residual_thickness_mm for t in found if t.rule.residual_thickness_mm] == [minimum]


def test_db_minimum_thickness_rules_do_not_apply_to_other_wires() -> None:
    found = thresholds(WIRES["CTA120"], PRESETS["db-ril-997"])
    assert [t.worn_fraction for t in found] == [0.20]
    assert found[0].residual_thickness_mm == pytest.approx(9.80, abs=0.01)


def test_china_rules() -> None:
    policy = PRESETS["china-maintenance-rules"]
    found = thresholds(WIRES["CTA120"], policy)
    assert [(t.level, t.scope, t.worn_fraction, t.rule.inclusive) for t in found] == [
        ("plan", "anchor_section_average", 0.25, False),
        ("urgent", "local", 0.30, False),
        ("critical", "local", 0.40, True),
    ]
    # wire-profiles.md equivalents, CTA120: 25 % -> 9.26 mm, 30 % -> 8.75 mm
    assert found[0].residual_thickness_mm == pytest.approx(9.26, abs=0.01)
    assert found[1].residual_thickness_mm == pytest.approx(8.75, abs=0.01)


def test_indian_railways_107_condemned_at_8_25() -> None:
    found = thresholds(WIRES["AC-107"], PRESETS["indian-railways-actm"])
    assert [(t.level, t.residual_thickness_mm) for t in found] == [("critical", 8.25)]
    assert found[0].worn_fraction == pytest.approx(0.30, abs=0.025)  # "about 30 % loss"
    assert thresholds(WIRES["AC-120"], PRESETS["indian-railways-actm"]) == []


def test_manufacturer_30_percent() -> None:
    (found,) = thresholds(WIRES["AC-100"], PRESETS["manufacturer-30pct"])
    assert found.residual_thickness_mm == pytest.approx(8.27, abs=0.01)
    assert found.wear_width_mm == pytest.approx(11.11, abs=0.01)


GOOD_RULE = 'level = "urgent"\nscope = "local"\nworn_fraction = 0.2\n'


def _policy_text(rule: str = GOOD_RULE, head: str = 'source = "test"\n') -> str:
    return f"[policies.mine]\n{head}\n[[policies.mine.rules]]\n{rule}"


def test_user_policy_text_and_file(tmp_path: Path) -> None:
    policies = parse_policies(_policy_text(), origin="mine.toml")
    assert policies["mine"].rules == (LimitRule(level="urgent", scope="local", worn_fraction=0.2),)
    path = tmp_path / "mine.toml"
    path.write_text(_policy_text())
    assert load_policies(path) == policies
    assert load_policies(str(path)) == policies


@pytest.mark.parametrize(
    ("rule", "expected"),
    [
        (GOOD_RULE.replace("0.2", '"20 %"'), "rule 1: worn_fraction must be a number between 0"),
        (GOOD_RULE.replace("0.2", "20"), "rule 1: worn_fraction must be a number between 0"),
        (GOOD_RULE.replace("0.2", "true"), "rule 1: worn_fraction must be a number"),
        (GOOD_RULE.replace('"urgent"', '"soon"'), "rule 1: level must be one of plan, urgent"),
        (GOOD_RULE.replace('"local"', '"span"'), "rule 1: scope must be one of local"),
        (GOOD_RULE + "residual_thickness_mm = 9.0\n", "rule 1: give exactly one of"),
        ('level = "plan"\nscope = "local"\n', "rule 1: give exactly one of"),
        (GOOD_RULE + "wire_type = ['AC-80']\n", "rule 1: unknown key 'wire_type'"),
        (GOOD_RULE + "wire_types = 'AC-80'\n", "rule 1: wire_types must be a list"),
        (GOOD_RULE + "inclusive = 'yes'\n", "rule 1: inclusive must be true or false"),
        (
            'level = "plan"\nscope = "local"\nresidual_thickness_mm = -1\n',
            "rule 1: residual_thickness_mm must be a positive number",
        ),
        ("scope = 'local'\nworn_fraction = 0.2\n", "rule 1: missing key 'level'"),
    ],
)
def test_bad_rule_is_one_clear_line(tmp_path: Path, rule: str, expected: str) -> None:
    path = tmp_path / "limits.toml"
    path.write_text(_policy_text(rule))
    with pytest.raises(UserError) as caught:
        load_policies(path)
    message = str(caught.value)
    assert message.startswith(f"{path}: policy 'mine' {expected}"), message
    assert "\n" not in message


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("[policies.mine\n", "invalid TOML"),
        ("", "no policies"),
        ("[limits]\nx = 1\n", "unknown key 'limits'"),
        (_policy_text(head="descripton = 'x'\n"), "policy 'mine': unknown key 'descripton'"),
        (_policy_text(head="source = 3\n"), "policy 'mine': source must be a string"),
        ("[policies.mine]\nsource = 'x'\n", "policy 'mine': needs at least one"),
    ],
)
def test_malformed_policy_file_is_one_clear_line(tmp_path: Path, text: str, expected: str) -> None:
    path = tmp_path / "limits.toml"
    path.write_text(text)
    with pytest.raises(UserError) as caught:
        load_policies(path)
    message = str(caught.value)
    assert message.startswith(f"{path}: ") and expected in message, message
    assert "\n" not in message


def test_missing_policy_file(tmp_path: Path) -> None:
    with pytest.raises(UserError, match=r"nowhere\.toml: policy file not found"):
        load_policies(tmp_path / "nowhere.toml")


def test_unknown_policy_lists_known_ones() -> None:
    with pytest.raises(UserError, match=r"unknown policy 'db' \(known: china-maintenance-rules, "):
        select_policy(PRESETS, "db")


def test_threshold_the_profile_cannot_reach_names_policy_rule_and_wire() -> None:
    rule = LimitRule(level="critical", scope="local", residual_thickness_mm=12.0)
    policy = LimitPolicy(name="thick", description="", source="", rules=(rule,))
    assert thresholds(WIRES["AC-120"], policy)[0].residual_thickness_mm == 12.0
    with pytest.raises(UserError, match=r"policy 'thick' rule 1 .*AC-80"):
        thresholds(WIRES["AC-80"], policy)  # 10.6 mm new


def test_limit_rule_checks_itself() -> None:
    with pytest.raises(ValueError, match="exactly one"):
        LimitRule(level="plan", scope="local")
    with pytest.raises(ValueError, match="level"):
        LimitRule(level="later", scope="local", worn_fraction=0.2)


def test_config_names_a_preset_or_a_file(tmp_path: Path) -> None:
    assert policy_from_config(None, presets=PRESETS) is None
    chosen = policy_from_config({"policy": "db-ril-997"}, presets=PRESETS)
    assert chosen == PRESETS["db-ril-997"]
    (tmp_path / "own.toml").write_text(_policy_text())
    config = tmp_path / "config.toml"
    own = policy_from_config({"file": "own.toml"}, presets=PRESETS, config_path=config)
    assert own is not None and own.name == "mine"
    with pytest.raises(UserError, match=r"config.toml: \[limits\]: unknown key 'polcy'"):
        policy_from_config({"polcy": "x"}, presets=PRESETS, config_path=config)
    with pytest.raises(UserError, match="name a policy"):
        policy_from_config({}, presets=PRESETS, config_path=config)
    with pytest.raises(UserError, match="unknown policy 'nope'"):
        policy_from_config({"policy": "nope"}, presets=PRESETS)
