"""Machine configuration: configs/machine.toml -> checked -> generated ST (FB_MachineConfig).

The carousel setup (the Logosol "Rotary toolchanger" page), the changer's timing and the simulated mechanics
live in one TOML file that integrators edit.  `plc machine check` rejects a bad file with `file:line: error`
lines before anything runs; `plc machine generate` writes st_src/app/generated/FB_MachineConfig.st, a function
block whose outputs are the configuration structures (an FB, because MATIEC rejects a FUNCTION called without
arguments).  `plc machine check` also fails when the generated file is not what the TOML says (drift).

A machine "with fixed pockets" (the seed's rack changer: no carousel, the spindle fetches each tool from its own
rack position) has a [rack] section instead of [carousel]: FixedPockets is TRUE (a prepare never turns anything),
the positioner gets a neutral configuration it never uses, and [rack] x/y/grip_z describe the rack for the
simulated plant (the sequences carry the same positions as Q coordinates).
"""
from __future__ import annotations

import argparse
import re
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from .diagnostics import FILE_LINE, Diagnostic, Pos

DEFAULT_CONFIG = Path("configs") / "machine.toml"
DEFAULT_OUT = Path("st_src") / "app" / "generated" / "FB_MachineConfig.st"

INPUTS = {"home+pocket": "InputsHomePocket", "home+pocket+code": "InputsHomePocketCode",
          "home+code": "InputsHomeCode", "pocket+code": "InputsPocketCode", "code": "InputsCodeOnly"}
OUTPUTS = {"single-positive": "OutputsSinglePositive", "single-negative": "OutputsSingleNegative",
           "enable+positive-dir": "OutputsEnablePositiveDir", "enable+negative-dir": "OutputsEnableNegativeDir",
           "separate": "OutputsSeparateDirections"}
HOMING = {"none": "HomingNone", "positive": "HomingPositive", "negative": "HomingNegative",
          "first-pocket": "HomingFirstPocket"}
CODE_CHECK = {"not-controlled": "CodeOrderNotControlled", "valid-only": "CodeValidOnly",
              "valid-and-zero": "CodeValidAndZero"}


@dataclass
class Checker:
    path: Path
    text: str
    problems: list[Diagnostic] = field(default_factory=list)

    def line_of(self, section: str, key: str | None = None) -> int:
        """Line of `key` inside `[section]` (or of the section header), 1 when not found."""
        lines = self.text.splitlines()
        in_sec = False
        for n, raw in enumerate(lines, 1):
            s = raw.split("#", 1)[0].strip()
            m = re.fullmatch(r"\[([^\]]+)\]", s)
            if m:
                in_sec = m.group(1).strip() == section
                if in_sec and key is None:
                    return n
                continue
            if in_sec and key is not None and re.match(rf"{re.escape(key)}\s*=", s):
                return n
        return 1

    def problem(self, line: int, message: str) -> None:
        """An error at `line` of the configuration, written `file:line: error: message`."""
        self.problems.append(Diagnostic("error", Pos(str(self.path), line, 0), message, layout=FILE_LINE))

    def error(self, section: str, key: str | None, message: str) -> None:
        self.problem(self.line_of(section, key), message)


SCHEMA = {
    "carousel": {
        "pockets": (int, 2, 50), "inputs": (INPUTS,), "outputs": (OUTPUTS,), "homing": (HOMING,),
        "code_inputs": (int, 1, 6), "code_check": (CODE_CHECK,), "debounce_scans": (int, 1, 100),
        "home_timeout_ms": (int, 0, 600000), "pocket_timeout_ms": (int, 0, 600000), "stop_delay_ms": (int, 0, 10000),
        "invert_home": (bool,), "invert_pocket": (bool,), "invert_on": (bool,), "invert_plus_dir": (bool,),
        "invert_minus_dir": (bool,), "invert_code": (list, bool), "pocket_codes": (list, int),
    },
    "rack": {"positions": (int, 1, 50), "x": (list, float), "y": (list, float), "grip_z": (float, -100000, 100000),
             "tolerance": (float, 0.001, 100)},
    "changer": {"brake_release_ms": (int, 0, 10000), "auto_home": (bool,), "tool_sensor": (bool,)},
    "simulation": {"pocket_time_ms": (int, 1, 10000), "coast_ms": (int, 0, 10000), "skew_scans": (int, 0, 100),
                   "arm_travel_ms": (int, 1, 60000), "collet_ms": (int, 1, 60000), "brake_ms": (int, 0, 60000)},
}
REQUIRED = {"carousel": ("pockets", "inputs", "outputs", "homing")}
REQUIRED_RACK = {"rack": ("positions", "x", "y", "grip_z")}
# the positioner's configuration on a rack machine: never commanded, neutral (no homing, nothing to count)
RACK_ROTARY = {"inputs": "code", "outputs": "enable+positive-dir", "homing": "none"}


def load(path: Path) -> tuple[dict | None, Checker]:
    try:
        text = path.read_text()
    except OSError as e:
        ck = Checker(path, "")
        ck.problem(0, f"cannot read: {e.strerror}")
        return None, ck
    ck = Checker(path, text)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        m = re.search(r"line (\d+)", str(e))
        ck.problem(int(m.group(1)) if m else 1, f"not valid TOML: {e}")
        return None, ck
    for sec, val in data.items():
        if sec not in SCHEMA:
            ck.error(sec, None, f"unknown section [{sec}] (expected {', '.join('[' + s + ']' for s in SCHEMA)})")
            continue
        if not isinstance(val, dict):
            ck.error(sec, None, f"{sec} must be a table")
            continue
        for key, v in val.items():
            rule = SCHEMA[sec].get(key)
            if rule is None:
                ck.error(sec, key, f"[{sec}] {key}: unknown setting")
                continue
            check_value(ck, sec, key, v, rule)
    if "rack" in data and "carousel" in data:
        ck.error("rack", None, "a machine has either a [carousel] or a [rack] (fixed pockets), not both")
    for sec, keys in (REQUIRED_RACK if "rack" in data else REQUIRED).items():
        for k in keys:
            if k not in data.get(sec, {}):
                ck.error(sec, None, f"[{sec}] {k} is required")
    if not ck.problems:
        cross_checks(ck, data)
    return data, ck


def check_value(ck: Checker, sec: str, key: str, v, rule) -> None:
    kind = rule[0]
    if isinstance(kind, dict):
        if v not in kind:
            ck.error(sec, key, f"[{sec}] {key}: '{v}' is not one of {', '.join(kind)}")
    elif kind is bool:
        if not isinstance(v, bool):
            ck.error(sec, key, f"[{sec}] {key}: expected true or false")
    elif kind is int:
        if isinstance(v, bool) or not isinstance(v, int) or not (rule[1] <= v <= rule[2]):
            ck.error(sec, key, f"[{sec}] {key}: expected an integer {rule[1]}..{rule[2]}, got {v!r}")
    elif kind is float:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (rule[1] <= v <= rule[2]):
            ck.error(sec, key, f"[{sec}] {key}: expected a number {rule[1]:g}..{rule[2]:g}, got {v!r}")
    elif kind is list:
        want = (int, float) if rule[1] is float else rule[1]
        if not isinstance(v, list) or not all(isinstance(x, want) and not (rule[1] is not bool and isinstance(x, bool))
                                              for x in v):
            what = {bool: "true/false", int: "integers", float: "numbers"}[rule[1]]
            ck.error(sec, key, f"[{sec}] {key}: expected a list of {what}")


def cross_checks(ck: Checker, data: dict) -> None:
    if "rack" in data:
        rack = data["rack"]
        for key in ("x", "y"):
            if len(rack[key]) != rack["positions"]:
                ck.error("rack", key, f"[rack] {key}: {len(rack[key])} values for {rack['positions']} positions "
                         "(one per position)")
        return
    car = data["carousel"]
    pockets = car["pockets"]
    uses_codes = "code" in car["inputs"]
    codes = car.get("pocket_codes", [])
    n_inputs = car.get("code_inputs", 3)
    if len(car.get("invert_code", [])) > 6:
        ck.error("carousel", "invert_code", "[carousel] invert_code: at most 6 code inputs")
    if uses_codes:
        if len(codes) != pockets:
            ck.error("carousel", "pocket_codes",
                     f"[carousel] pocket_codes: {len(codes)} codes for {pockets} pockets (one code per pocket)")
        top = (1 << n_inputs) - 1
        bad = [c for c in codes if not (1 <= c <= top)]
        if bad:
            ck.error("carousel", "pocket_codes",
                     f"[carousel] pocket_codes: {bad[0]} is outside 1..{top} ({n_inputs} code inputs)")
        dup = sorted({c for c in codes if codes.count(c) > 1})
        if dup:
            ck.error("carousel", "pocket_codes", f"[carousel] pocket_codes: code {dup[0]} is used twice")
    if car["inputs"] == "home+pocket" and car["homing"] == "none":
        ck.error("carousel", "homing", "[carousel] homing: counting pockets (inputs = home+pocket) needs homing")
    if car["outputs"].startswith("single") and car["homing"] == ("negative" if "positive" in car["outputs"]
                                                                 else "positive"):
        ck.error("carousel", "homing", "[carousel] homing: a single-direction carousel cannot home the other way")


def ms(v: int) -> str:
    return f"T#{v}ms"


def st_bool(v: bool) -> str:
    return "TRUE" if v else "FALSE"


def thousandths(v: float) -> int:
    return int(round(v * 1000))


def generate(data: dict, source: str) -> str:
    rack = data.get("rack")
    car = data["carousel"] if rack is None else dict(RACK_ROTARY, pockets=rack["positions"])
    chg = data.get("changer", {})
    sim = data.get("simulation", {})
    out = [f"(* Generated by `plc machine generate` from {source}: do not edit; edit the TOML and regenerate.",
           "   FB_MachineConfig - the machine's configuration as structures; call it once per scan (no inputs). *)",
           "FUNCTION_BLOCK FB_MachineConfig",
           "VAR_OUTPUT",
           "    Rotary : ST_RotaryConfig;           (* the carousel: FB_RotaryPositioner.Config *)",
           "    Plant : ST_CarouselPlantConfig;     (* simulated carousel mechanics *)",
           "    ChangerPlant : ST_ChangerPlantConfig; (* simulated arm, collet and brake *)",
           "    BrakeReleaseTime : TIME;            (* brake released this long before a pre-positioning turn *)",
           "    AutoHome : BOOL;                    (* run the Home sequence by itself after power-up *)",
           "    ToolSensor : BOOL;                  (* a tool-present sensor (ToolPresent) decides an unknown tool *)",
           "    FixedPockets : BOOL;                (* a rack (fixed pockets): no carousel, prepares turn nothing *)",
           "    RackPlant : ST_RackPlantConfig;     (* simulated rack, collet and tool-present sensor *)",
           "END_VAR",
           f"Rotary.pockets := {car['pockets']};",
           f"Rotary.inputDescription := E_RotaryInputs#{INPUTS[car['inputs']]};",
           f"Rotary.outputDescription := E_RotaryOutputs#{OUTPUTS[car['outputs']]};",
           f"Rotary.homing := E_RotaryHoming#{HOMING[car['homing']]};",
           f"Rotary.codeInputs := {car.get('code_inputs', 3)};",
           f"Rotary.codeCheck := E_CodeCheckLevel#{CODE_CHECK[car.get('code_check', 'not-controlled')]};",
           f"Rotary.codeDebounceScans := {car.get('debounce_scans', 3)};",
           f"Rotary.homeTimeout := {ms(car.get('home_timeout_ms', 25000))};",
           f"Rotary.pocketTimeout := {ms(car.get('pocket_timeout_ms', 10000))};",
           f"Rotary.stopDelay := {ms(car.get('stop_delay_ms', 0))};",
           f"Rotary.invertHome := {st_bool(car.get('invert_home', False))};",
           f"Rotary.invertPocket := {st_bool(car.get('invert_pocket', False))};",
           f"Rotary.invertOn := {st_bool(car.get('invert_on', False))};",
           f"Rotary.invertPlusDir := {st_bool(car.get('invert_plus_dir', False))};",
           f"Rotary.invertMinusDir := {st_bool(car.get('invert_minus_dir', False))};"]
    for i, v in enumerate(car.get("invert_code", []), 1):
        out.append(f"Rotary.invertCode[{i}] := {st_bool(v)};")
    for i, c in enumerate(car.get("pocket_codes", []), 1):
        out.append(f"Rotary.pocketCode[{i}] := {c};")
    out += [f"Plant.pocketTime := {ms(sim.get('pocket_time_ms', 100))};",
            f"Plant.coastTime := {ms(sim.get('coast_ms', 0))};",
            f"Plant.skewScans := {sim.get('skew_scans', 0)};",
            f"ChangerPlant.pockets := {car['pockets']};",
            f"ChangerPlant.armTravelTime := {ms(sim.get('arm_travel_ms', 600))};",
            f"ChangerPlant.colletTime := {ms(sim.get('collet_ms', 100))};",
            f"ChangerPlant.brakeTime := {ms(sim.get('brake_ms', 50))};",
            f"BrakeReleaseTime := {ms(chg.get('brake_release_ms', 500))};",
            f"AutoHome := {st_bool(chg.get('auto_home', True))};",
            f"ToolSensor := {st_bool(chg.get('tool_sensor', False))};",
            f"FixedPockets := {st_bool(rack is not None)};"]
    if rack is not None:
        out += [f"RackPlant.positions := {rack['positions']};",
                f"RackPlant.gripZ := {thousandths(rack['grip_z'])};",
                f"RackPlant.tolerance := {thousandths(rack.get('tolerance', 0.5))};",
                f"RackPlant.colletTime := {ms(sim.get('collet_ms', 100))};"]
        for i, (x, y) in enumerate(zip(rack["x"], rack["y"]), 1):
            out += [f"RackPlant.x[{i}] := {thousandths(x)};", f"RackPlant.y[{i}] := {thousandths(y)};"]
    out.append("END_FUNCTION_BLOCK")
    return "\n".join(out) + "\n"


def report(ck: Checker) -> None:
    for d in ck.problems:
        print(d.render(), file=sys.stderr)


def check_and_generate(config: Path, out: Path, write: bool, label: str | None = None) -> int:
    """Check `config`; write `out` (write=True) or fail when it differs (drift). `label` names the source in the
    generated header (default: the path as given), so the file is the same from wherever it is generated."""
    data, ck = load(config)
    if ck.problems:
        report(ck)
        return 1
    text = generate(data, label or config.as_posix())
    if write:
        out.parent.mkdir(parents=True, exist_ok=True)
        if not out.exists() or out.read_text() != text:
            out.write_text(text)
            print(f"wrote {out}", file=sys.stderr)
        return 0
    if not out.exists() or out.read_text() != text:
        print(f"{out}: error: out of date with {config}: run `plc machine generate`", file=sys.stderr)
        return 1
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("machine", help="check the machine configuration / generate its ST",
                       description="Check configs/machine.toml (carousel, changer timing, simulation) with "
                                   "file:line errors, and generate the ST function block FB_MachineConfig from it.")
    p.add_argument("action", choices=["check", "generate"], help="check (also fails on drift) or generate")
    p.add_argument("--config", type=Path, default=DEFAULT_CONFIG, help=f"default {DEFAULT_CONFIG}")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"default {DEFAULT_OUT}")
    p.set_defaults(func=lambda a: check_and_generate(a.config, a.out, a.action == "generate"))
