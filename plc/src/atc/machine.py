"""Machine configuration: machines/default/machine.toml -> checked -> generated ST (FB_MachineConfig).

The carousel setup (the Logosol "Rotary toolchanger" page), the changer's timing and the simulated mechanics
live in one TOML file that integrators edit.  `plc machine check` rejects a bad file with `file:line: error`
lines before anything runs; `plc machine generate` writes st_src/app/generated/FB_MachineConfig.st, a function
block whose outputs are the configuration structures (an FB, because MATIEC rejects a FUNCTION called without
arguments).  `plc machine check` also fails when the generated file is not what the TOML says (drift).

A machine "with fixed pockets" (a Logosol rack changer: no carousel, the spindle fetches each tool from its own
rack position) has a [rack] section instead of [carousel]: FixedPockets is TRUE (a prepare never turns anything),
the positioner gets a neutral configuration it never uses, and [rack] x/y/grip_z describe the rack for the
simulated plant (the sequences carry the same positions as Q coordinates).
"""
from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

from plc import tomlconf
from plc.diagnostics import FILE_LINE, Diagnostic
from plc.project import where
from plc.timelit import ms_literal
from plc.tomlconf import Bool, Field, Int, ListOf, Number, OneOf, Str, Table

DEFAULT_OUT = Path("st_src") / "app" / "generated" / "FB_MachineConfig.st"
MAP_FILE = "modbus_map/map.toml"
TOOL_TABLE = "configs/linuxcnc/atc-sim.tbl"
SEQ_TABLES = "st_src/sequence/generated/SequenceTables.st"

INPUTS = {"home+pocket": "InputsHomePocket", "home+pocket+code": "InputsHomePocketCode",
          "home+code": "InputsHomeCode", "pocket+code": "InputsPocketCode", "code": "InputsCodeOnly"}
OUTPUTS = {"single-positive": "OutputsSinglePositive", "single-negative": "OutputsSingleNegative",
           "enable+positive-dir": "OutputsEnablePositiveDir", "enable+negative-dir": "OutputsEnableNegativeDir",
           "separate": "OutputsSeparateDirections"}
HOMING = {"none": "HomingNone", "positive": "HomingPositive", "negative": "HomingNegative",
          "first-pocket": "HomingFirstPocket"}
# what a simulated code disc shows between the pockets' code windows ([simulation] code_between)
CODE_BETWEEN = {"nearest": "the nearest pocket's code: the code changes at mid-pitch (a sector disc)",
                "zero": "code 0 outside a window around each pocket centre (a gap disc; code_window_pct)"}
SIM_SCAN_MS = 4          # the simulated task's interval (FB_AtcMachine.CycleTime)
CODE_MODES_WITHOUT_POCKET = ("home+code", "code")
CODE_CHECK = {"not-controlled": "CodeOrderNotControlled", "valid-only": "CodeValidOnly",
              "valid-and-zero": "CodeValidAndZero"}


@dataclass
class Checker:
    """The problems of one machine description, each at the place of its key (the file read with plc.tomlconf)."""
    path: Path
    doc: tomlconf.Document
    problems: list[Diagnostic] = field(default_factory=list)
    warnings: list[Diagnostic] = field(default_factory=list)

    def error(self, section: str, key: str | None, message: str, hint: str | None = None) -> None:
        """An error at `key` of `[section]` (at the section when the key is not written)."""
        self.problems.append(self.doc.diagnostic("error", _path(section, key), message, hint))

    def warn(self, section: str, key: str | None, message: str) -> None:
        """A warning at `key` of `[section]`: the machine works as described, but not as meant (say why)."""
        self.warnings.append(self.doc.diagnostic("warning", _path(section, key), message))

    def line(self, section: str, key: str | None = None) -> int:
        """The line of `key` of `[section]` (of the section when the key is not written; 1 when neither is)."""
        return self.doc.pos(_path(section, key)).line


def _path(section: str, key: str | None) -> tuple:
    return (section,) if key is None else (section, key)


KINDS = {"carousel": "rotary toolchanger (the Logosol manual's carousel): [carousel] and [channels]",
         "fixed-pockets": "a rack of tool holders the spindle visits (no carousel): [rack]"}
KIND_SECTION = {"carousel": "carousel", "fixed-pockets": "rack"}
MAX_POCKETS = 50            # the Logosol limit; the ST pocket tables are ARRAY[1..50]
MAX_CHANNEL = 799           # discrete inputs / coils of OpenPLC's map (%IX0.0..%IX99.7, %QX0.0..%QX99.7)

# The carousel lines of the Logosol manual: [channels] key -> register-map signal, table, description.
LINES = {
    "home": ("CarouselHome", "discrete_input", "carousel home input (Logosol Home Input)"),
    "pocket": ("CarouselPocket", "discrete_input", "carousel pocket input (Logosol Pocket Input)"),
    **{f"code{i}": (f"CarouselCode{i}", "discrete_input",
                    f"carousel code input {i} (Logosol Code Input {i}, weight {1 << (i - 1)})") for i in range(1, 7)},
    "on": ("CarouselMotorOn", "coil", "carousel Output ON (wire level after invert_on); safe: its Stop-row level"),
    "plus_dir": ("CarouselDirPositive", "coil",
                 "carousel Output +DIR (wire level after invert_plus_dir); safe: its Stop-row level"),
    "minus_dir": ("CarouselDirNegative", "coil",
                  "carousel Output -DIR (wire level after invert_minus_dir); safe: its Stop-row level"),
}
# the changer lines the sequences use by channel (FB_MachineConfig.Channels): ST field -> register-map signal
MAP_CHANNELS = {"armAtForward": "ArmAtForward", "armAtReverse": "ArmAtReverse", "colletOpened": "ColletOpened",
                "lengthSensor": "ToolLengthSensor", "brakeOff": "BrakeOff", "armForward": "ArmForward",
                "colletOpen": "ColletOpen", "toolPresent": "ToolPresent",
                **{f"userIn{n}": f"UserIn{n}" for n in range(4, 8)},       # the user procedures' I/O
                **{f"userOut{n}": f"UserOut{n}" for n in range(4, 8)}}


CHANNEL = Int(0, MAX_CHANNEL)
INTEGERS, BOOLS, NUMBERS = ListOf(Int(), "integers"), ListOf(Bool(), "true/false"), ListOf(Number(), "numbers")
# the sections of a machine description; [carousel] or [rack], as the kind says (KIND_SECTION)
SCHEMA = {
    "machine": Table((Field("kind", OneOf(tuple(KINDS)), "what changes the tools", default="carousel"),
                      Field("name", Str()))),
    "channels": Table((Field("home", CHANNEL, "Home Input"), Field("pocket", CHANNEL, "Pocket Input"),
                       Field("code", INTEGERS, "Code Input 1..6"), Field("on", CHANNEL, "Output ON"),
                       Field("plus_dir", CHANNEL, "Output +DIR"), Field("minus_dir", CHANNEL, "Output -DIR"))),
    "sequences": Table((Field("index", Str(), "the sequence set's index, relative to the project"),)),
    "carousel": Table((
        Field("pockets", Int(2, MAX_POCKETS), "pocket n holds tool n", required=True),
        Field("inputs", OneOf(tuple(INPUTS)), "the sensors that say where the carousel is", required=True),
        Field("outputs", OneOf(tuple(OUTPUTS)), "the motor lines", required=True),
        Field("homing", OneOf(tuple(HOMING)), "how the carousel finds its home", required=True),
        Field("code_inputs", Int(1, 6)), Field("code_check", OneOf(tuple(CODE_CHECK))),
        Field("debounce_scans", Int(1, 100)), Field("home_timeout_ms", Int(0, 600000)),
        Field("pocket_timeout_ms", Int(0, 600000)), Field("stop_delay_ms", Int(0, 10000)),
        Field("invert_home", Bool()), Field("invert_pocket", Bool()), Field("invert_on", Bool()),
        Field("invert_plus_dir", Bool()), Field("invert_minus_dir", Bool()), Field("invert_code", BOOLS),
        Field("pocket_codes", INTEGERS), Field("centre_on_code", Bool()))),
    "rack": Table((
        Field("positions", Int(1, 50), "rack position n holds tool n", required=True),
        Field("x", NUMBERS, "the X of each position, mm", required=True),
        Field("y", NUMBERS, "the Y of each position, mm", required=True),
        Field("grip_z", Number(-100000, 100000), "the Z where the spindle grips a holder, mm", required=True),
        Field("tolerance", Number(0.001, 100)))),
    "changer": Table((Field("brake_release_ms", Int(0, 10000)), Field("auto_home", Bool()),
                      Field("tool_sensor", Bool()),
                      Field("worn_out", OneOf(("soft", "hard")), "a worn tool without a sister (docs/tools.md): "
                            "soft 109, the program goes on; hard -109, it aborts"))),
    "simulation": Table((
        Field("pocket_time_ms", Int(1, 10000)), Field("coast_ms", Int(0, 10000)), Field("skew_scans", Int(0, 100)),
        Field("arm_travel_ms", Int(1, 60000)), Field("collet_ms", Int(1, 60000)), Field("brake_ms", Int(0, 60000)),
        Field("sensor_window_pct", Int(1, 49)), Field("code_between", OneOf(tuple(CODE_BETWEEN))),
        Field("code_window_pct", Int(1, 49)))),
}
DEFAULT_SEQUENCES = "configs/sequences/sequences.toml"
# the positioner's configuration on a rack machine: never commanded, neutral (no homing, nothing to count)
RACK_ROTARY = {"inputs": "code", "outputs": "enable+positive-dir", "homing": "none"}


def load(path: Path, label: str | None = None) -> tuple[dict | None, Checker]:
    """Read and check a machine description; problems are reported at `label` (default: the path)."""
    name = str(label or path)
    try:
        doc = tomlconf.read(path, name, layout=FILE_LINE)
    except tomlconf.TomlError as exc:
        ck = Checker(Path(name), tomlconf.Document(name, "", {}, {}, layout=FILE_LINE))
        ck.problems.append(exc.diagnostic)
        return None, ck
    ck = Checker(Path(name), doc)
    data = doc.data
    checked = tomlconf.check_sections(doc, dict(SCHEMA, carousel=None, rack=None))   # the kind says which
    machine = checked.get("machine", tomlconf.Checked())
    kind = machine.get("kind", "carousel")
    mine = KIND_SECTION[kind]
    for sec in ("carousel", "rack"):
        if sec in data and sec != mine and "kind" not in machine.bad:
            want = next(k for k, v in KIND_SECTION.items() if v == sec)
            doc.error((sec,), f"[{sec}] belongs to a machine of kind \"{want}\"; [machine] kind = \"{kind}\" "
                              f"is described by [{mine}]")
    table = data.get(mine, {})
    if isinstance(table, dict):
        SCHEMA[mine].check(doc, (mine,), table, f"[{mine}]")
    ck.problems.extend(doc.in_file_order())
    doc.diagnostics.clear()
    if not ck.problems:
        cross_checks(ck, data)
    return data, ck


def used_lines(car: dict) -> list[str]:
    """The [channels] keys of the carousel lines the input and output descriptions use, in LINES order."""
    inputs, outputs = car["inputs"], car["outputs"]
    keys = []
    if "home" in inputs:
        keys.append("home")
    if "pocket" in inputs:
        keys.append("pocket")
    if "code" in inputs:
        keys += [f"code{i}" for i in range(1, car.get("code_inputs", 3) + 1)]
    if outputs.startswith("enable"):
        keys.append("on")
    if outputs in ("single-positive", "enable+positive-dir", "separate"):
        keys.append("plus_dir")
    if outputs in ("single-negative", "enable+negative-dir", "separate"):
        keys.append("minus_dir")
    return keys


def line_channels(data: dict) -> dict[str, int]:
    """[channels] key -> channel of every used carousel line (code inputs as code1..code6)."""
    ch = data.get("channels", {})
    codes = ch.get("code", [])
    out = {}
    for key in used_lines(data["carousel"]) if "carousel" in data else []:
        if key.startswith("code"):
            i = int(key[4:])
            if i <= len(codes):
                out[key] = codes[i - 1]
        elif key in ch:
            out[key] = ch[key]
    return out


def is_rack(data: dict) -> bool:
    """The machine has fixed pockets ([machine] kind = "fixed-pockets", described by [rack])."""
    return "rack" in data


def pockets(data: dict) -> int:
    """Tool places of the machine: carousel pockets, or rack positions (pocket / position n holds tool n)."""
    return data["rack"]["positions"] if is_rack(data) else data["carousel"]["pockets"]


def cross_checks(ck: Checker, data: dict) -> None:
    if is_rack(data):                   # no carousel: none of its checks apply, no carousel lines to place
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
    inverted = car.get("invert_code")
    if inverted is not None and len(inverted) > 6:
        ck.error("carousel", "invert_code", "[carousel] invert_code: at most 6 code inputs")
    elif inverted is not None and uses_codes and len(inverted) < n_inputs:
        ck.error("carousel", "invert_code",
                 f"[carousel] invert_code: {len(inverted)} values for {n_inputs} code inputs (code_inputs = "
                 f"{n_inputs}): one per code input, true where the input is active low")
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
    check_simulation(ck, data)
    check_channels(ck, data)


def centres_on_code(car: dict) -> bool:
    """[carousel] centre_on_code, by default TRUE in the code modes without a pocket input."""
    return car.get("centre_on_code", car["inputs"] in CODE_MODES_WITHOUT_POCKET)


def code_between(data: dict) -> str:
    return data.get("simulation", {}).get("code_between", "nearest")


def sensor_window_ms(sim: dict) -> float:
    """Half width of the simulated pocket/home sensor window, the tolerance where the arm meets a holder."""
    return sim.get("pocket_time_ms", 100) * sim.get("sensor_window_pct", 20) / 100


def code_window_ms(sim: dict) -> float:
    return sim.get("pocket_time_ms", 100) * sim.get("code_window_pct", sim.get("sensor_window_pct", 20)) / 100


def check_simulation(ck: Checker, data: dict) -> None:
    """The centring settings and the simulated code disc; then where the simulated carousel stops: a warning
    with the numbers when it stops outside the window where the arm meets the holder."""
    car, sim = data["carousel"], data.get("simulation", {})
    if car.get("centre_on_code") and car["inputs"] not in CODE_MODES_WITHOUT_POCKET:
        ck.error("carousel", "centre_on_code", f"[carousel] centre_on_code: only for the code modes without a pocket "
                 f"input ({', '.join(CODE_MODES_WITHOUT_POCKET)}): with inputs = \"{car['inputs']}\" the pocket input "
                 "says where the centre is")
    if "code_window_pct" in sim and code_between(data) != "zero":
        ck.error("simulation", "code_window_pct", "[simulation] code_window_pct: applies to code_between = \"zero\" "
                 "(a gap disc); with a sector disc each code spans its whole pitch")
    if code_between(data) == "zero" and car.get("code_check") == "valid-only" and "code" in car["inputs"]:
        ck.error("simulation", "code_between", "[simulation] code_between = \"zero\": code_check = \"valid-only\" "
                 "faults on the code 0 between pockets (use \"nearest\", or code_check = \"valid-and-zero\")")
    if ck.problems:
        return
    t = sim.get("pocket_time_ms", 100)
    window = sensor_window_ms(sim)
    delay, coast = car.get("stop_delay_ms", 0), sim.get("coast_ms", 0)
    settle = car.get("debounce_scans", 3) * SIM_SCAN_MS
    codes = car.get("pocket_codes", [])
    if code_between(data) == "nearest":         # the bits that change from one pocket's code to the next
        changes = [bin(a ^ b).count("1") for a, b in zip(codes, codes[1:] + codes[:1], strict=True)]
        region = t
    else:                                       # from code 0 to the pocket's code
        changes = [bin(c).count("1") for c in codes]
        region = 2 * code_window_ms(sim)
    skew = sim.get("skew_scans", 0) * SIM_SCAN_MS * (max(changes, default=1) - 1)
    settle += skew                              # the code settles once its last bit changed
    if "code" not in car["inputs"]:
        arrival, how = -window, "at the pocket input's edge"
    elif "pocket" in car["inputs"]:
        arrival, how = max(-window, -region / 2 + settle), "at the pocket input's edge, with the code settled"
    elif centres_on_code(car):
        arrival, how = max(0.0, -region / 2 + settle), "centred on the code region"
    else:
        arrival, how = -region / 2 + settle, ("when the code settles after its region begins (centre_on_code = "
                                              "false)")
    offset = arrival + delay + coast
    if abs(offset) <= window:
        return
    side = "past" if offset > 0 else "before"
    fix = (f"lower stop_delay_ms ({delay}) or coast_ms ({coast})" if offset > 0 else
           "set centre_on_code = true" if car["inputs"] in CODE_MODES_WITHOUT_POCKET else
           f"raise stop_delay_ms to about {round(-arrival - coast)}")
    ck.warn("simulation", "pocket_time_ms" if "pocket_time_ms" in sim else None,
            f"[simulation] the simulated carousel stops about {abs(offset):.0f} ms {side} the pocket centre "
            f"({how}, {arrival:+.0f} ms; stop_delay_ms {delay}, coast_ms {coast}), outside the +-{window:g} ms where "
            f"the arm meets the holder (sensor_window_pct {sim.get('sensor_window_pct', 20)} of pocket_time_ms "
            f"{t}): simulated changes crash the plant (a fault, -121..-127), and a machine whose pocket takes as "
            f"long stops off centre too; {fix}")


def check_channels(ck: Checker, data: dict) -> None:
    """Every line the descriptions use has a channel; no two carousel lines share one."""
    car, ch = data["carousel"], data.get("channels")
    if ch is None:
        ck.error("carousel", None, "[channels] is required: the I/O channel of every carousel line "
                                   f"({', '.join(used_lines(car))})")
        return
    used = used_lines(car)
    n_codes = sum(1 for k in used if k.startswith("code"))
    if n_codes and len(ch.get("code", [])) < n_codes:
        ck.error("channels", "code" if "code" in ch else None,
                 f"[channels] code: {len(ch.get('code', []))} channel(s) for {n_codes} code inputs "
                 f"(code_inputs = {car.get('code_inputs', 3)})")
    for key in used:
        if not key.startswith("code") and key not in ch:
            ck.error("channels", None, f"[channels] {key} is required: inputs = \"{car['inputs']}\" / "
                                       f"outputs = \"{car['outputs']}\" use the {LINES[key][0]} line")
    for c in ch.get("code", []):
        if not 0 <= c <= MAX_CHANNEL:
            ck.error("channels", "code", f"[channels] code: channel {c} is outside 0..{MAX_CHANNEL}")
    seen: dict[tuple[str, int], str] = {}
    for key, channel in line_channels(data).items():
        table = LINES[key][1]
        other = seen.get((table, channel))
        if other is not None:
            ck.error("channels", "code" if key.startswith("code") else key,
                     f"[channels] {key} and {other} are both on {'input' if table == 'discrete_input' else 'output'} "
                     f"channel {channel}: two lines on one channel")
        else:
            seen[(table, channel)] = key


def sequences_index(data: dict, root: Path) -> Path:
    return root / data.get("sequences", {}).get("index", DEFAULT_SEQUENCES)


def tools_line(text: str) -> tuple[int, int | None]:
    """Line of `tools = N` in a sequences.toml's [machine] table and N (None when absent or not a number)."""
    try:
        doc = tomlconf.parse(text, "sequences.toml")
    except tomlconf.TomlError:
        return 1, None                  # the sequence tools report it
    machine = doc.data.get("machine")
    tools = machine.get("tools") if isinstance(machine, dict) else None
    if not isinstance(tools, int) or isinstance(tools, bool):
        return 1, None
    return doc.pos(("machine", "tools")).line, tools


def check_sequences(ck: Checker, data: dict, root: Path, label: str) -> None:
    """The sequence set's tool count covers the pockets (pocket n holds tool n)."""
    index = sequences_index(data, root)
    try:
        text = index.read_text()
    except OSError as e:
        ck.error("sequences", "index", f"[sequences] index: cannot read {index}: {e.strerror}")
        return
    line, tools = tools_line(text)
    places = pockets(data)
    sec, key = ("rack", "positions") if is_rack(data) else ("carousel", "pockets")
    check_sequence_outputs(ck, data, text, _rel(index, root))
    if tools != places:
        rel = _rel(index, root)
        ck.error(sec, key,
                 f"[{sec}] {key} = {places}, but {rel}:{line} has tools = {tools}: the sequences must cover "
                 f"tools 1..{places} ({'position' if is_rack(data) else 'pocket'} n holds tool n); "
                 "run `plc machine generate`, which writes it")


def check_sequence_outputs(ck: Checker, data: dict, text: str, rel: str) -> None:
    """No carousel motor line on a channel the sequences may write with OUT (two owners of one output)."""
    try:
        index = tomlconf.parse(text, rel)
    except tomlconf.TomlError:
        return                          # the sequence tools report it
    io = index.data.get("io")
    outputs = io.get("outputs", []) if isinstance(io, dict) else []
    channels: set[int] = set()
    for item in outputs if isinstance(outputs, list) else []:
        low, _, high = str(item).partition("-")
        if low.strip().isdigit() and (not high or high.strip().isdigit()):
            channels.update(range(int(low), int(high or low) + 1))
    line = index.pos(("io", "outputs")).line
    for key, channel in line_channels(data).items():
        if LINES[key][1] == "coil" and channel in channels:
            ck.error("channels", key, f"[channels] {key} = {channel} is also a sequence output ({rel}:{line} "
                                      f"[io] outputs): two owners of one output channel")


def _rel(path: Path, root: Path) -> str:
    try:
        return where(path).relative_to(where(root)).as_posix()
    except ValueError:
        return str(path)


def ms(v: int) -> str:
    return ms_literal(v)


def st_bool(v: bool) -> str:
    return "TRUE" if v else "FALSE"


def thousandths(v: float) -> int:
    return int(round(v * 1000))


def generate(data: dict, source: str, map_channels: dict[str, int]) -> str:
    """FB_MachineConfig: the machine description as ST structures. map_channels: ST_AtcChannels field -> channel
    of the changer lines the register map places (MAP_CHANNELS). A fixed-pocket machine gets a neutral positioner
    configuration it never commands (RACK_ROTARY) and its rack in RackPlant."""
    rack = data.get("rack")
    car = data["carousel"] if rack is None else dict(RACK_ROTARY, pockets=rack["positions"])
    chg = data.get("changer", {})
    sim = data.get("simulation", {})
    out = [f"(* Generated by `plc machine generate` from {source} and modbus_map/map.toml: do not edit; edit the",
           "   TOML and regenerate.",
           "   FB_MachineConfig - the machine's configuration as structures; call it once per scan (no inputs). *)",
           "FUNCTION_BLOCK FB_MachineConfig",
           "VAR_OUTPUT",
           "    Rotary : ST_RotaryConfig;           (* the carousel: FB_RotaryPositioner.Config *)",
           "    Plant : ST_CarouselPlantConfig;     (* simulated carousel mechanics *)",
           "    ChangerPlant : ST_ChangerPlantConfig; (* simulated arm, collet and brake *)",
           "    Channels : ST_AtcChannels;          (* I/O channels the application addresses by number *)",
           "    BrakeReleaseTime : TIME;            (* brake released this long before a pre-positioning turn *)",
           "    AutoHome : BOOL;                    (* run the Home sequence by itself after power-up *)",
           "    ToolSensor : BOOL;                  (* a tool-present sensor (ToolPresent) decides an unknown tool *)",
           "    ToolsWornHard : BOOL;               (* a worn tool without a sister is a hard refusal (-109) *)",
           "    FixedPockets : BOOL;                (* a rack (fixed pockets): no carousel, prepares turn nothing *)",
           "    RackPlant : ST_RackPlantConfig;     (* simulated rack, collet and tool-present sensor *)",
           "END_VAR",
           f"Rotary.pockets := {car['pockets']};",
           f"Rotary.inputDescription := {INPUTS[car['inputs']]};",
           f"Rotary.outputDescription := {OUTPUTS[car['outputs']]};",
           f"Rotary.homing := {HOMING[car['homing']]};",
           f"Rotary.codeInputs := {car.get('code_inputs', 3)};",
           f"Rotary.codeCheck := {CODE_CHECK[car.get('code_check', 'not-controlled')]};",
           f"Rotary.codeDebounceScans := {car.get('debounce_scans', 3)};",
           f"Rotary.homeTimeout := {ms(car.get('home_timeout_ms', 25000))};",
           f"Rotary.pocketTimeout := {ms(car.get('pocket_timeout_ms', 10000))};",
           f"Rotary.stopDelay := {ms(car.get('stop_delay_ms', 0))};",
           f"Rotary.centreOnCode := {st_bool(rack is None and centres_on_code(car))};",
           f"Rotary.invertHome := {st_bool(car.get('invert_home', False))};",
           f"Rotary.invertPocket := {st_bool(car.get('invert_pocket', False))};",
           f"Rotary.invertOn := {st_bool(car.get('invert_on', False))};",
           f"Rotary.invertPlusDir := {st_bool(car.get('invert_plus_dir', False))};",
           f"Rotary.invertMinusDir := {st_bool(car.get('invert_minus_dir', False))};"]
    for i, v in enumerate(car.get("invert_code", []), 1):
        out.append(f"Rotary.invertCode[{i}] := {st_bool(v)};")
    for i, c in enumerate(car.get("pocket_codes", []), 1):
        out.append(f"Rotary.pocketCode[{i}] := {c};")
    lines = line_channels(data)
    out += [f"Channels.home := {lines.get('home', -1)};",
            f"Channels.pocket := {lines.get('pocket', -1)};"]
    out += [f"Channels.{field_} := {map_channels.get(field_, -1)};" for field_ in MAP_CHANNELS]
    out += [f"Plant.pocketTime := {ms(sim.get('pocket_time_ms', 100))};",
            f"Plant.window := {ms(max(1, round(sensor_window_ms(sim))))};",
            f"Plant.codeGap := {st_bool(code_between(data) == 'zero')};",
            f"Plant.codeWindow := {ms(max(1, round(code_window_ms(sim))))};",
            f"Plant.coastTime := {ms(sim.get('coast_ms', 0))};",
            f"Plant.skewScans := {sim.get('skew_scans', 0)};",
            f"ChangerPlant.pockets := {car['pockets']};",
            f"ChangerPlant.armTravelTime := {ms(sim.get('arm_travel_ms', 600))};",
            f"ChangerPlant.colletTime := {ms(sim.get('collet_ms', 100))};",
            f"ChangerPlant.brakeTime := {ms(sim.get('brake_ms', 50))};",
            f"BrakeReleaseTime := {ms(chg.get('brake_release_ms', 500))};",
            f"AutoHome := {st_bool(chg.get('auto_home', True))};",
            f"ToolSensor := {st_bool(chg.get('tool_sensor', False))};",
            f"ToolsWornHard := {st_bool(chg.get('worn_out', 'soft') == 'hard')};",
            f"FixedPockets := {st_bool(rack is not None)};"]
    if rack is not None:
        out += [f"RackPlant.positions := {rack['positions']};",
                f"RackPlant.gripZ := {thousandths(rack['grip_z'])};",
                f"RackPlant.tolerance := {thousandths(rack.get('tolerance', 0.5))};",
                f"RackPlant.colletTime := {ms(sim.get('collet_ms', 100))};"]
        for i, (x, y) in enumerate(zip(rack["x"], rack["y"], strict=True), 1):
            out += [f"RackPlant.x[{i}] := {thousandths(x)};", f"RackPlant.y[{i}] := {thousandths(y)};"]
    out.append("END_FUNCTION_BLOCK")
    return "\n".join(out) + "\n"


# the simulated machine's first six tools (the LinuxCNC demo table); further tools get placeholder sizes
SIM_TOOLS = [(6.0, 10.0, "end mill 6 mm"), (8.0, 12.0, "end mill 8 mm"), (10.0, 14.0, "end mill 10 mm"),
             (12.0, 16.0, "end mill 12 mm"), (3.0, 8.0, "drill 3 mm"), (4.0, 9.0, "drill 4 mm")]


def tool_table(data: dict) -> str:
    """The LinuxCNC tool table of the simulated machine (generated from [carousel] pockets or [rack] positions):
    tool n in pocket n, as the changer holds them on its first start, in ascending pocket order (LinuxCNC 2.9
    lost a tool of a table whose pockets were out of order). No comment-only lines (LinuxCNC reads every line as
    a tool)."""
    rows = []
    for n in range(1, pockets(data) + 1):
        d, z, what = SIM_TOOLS[n - 1] if n <= len(SIM_TOOLS) else (2.0 + n % 10, 8.0 + n % 10, f"tool {n}")
        rows.append(f"T{n} P{n} D{d:.3f} Z+{z:.3f} ;{what}")
    return "\n".join(rows) + "\n"


def report(ck: Checker) -> None:
    for d in ck.problems + ck.warnings:
        print(d.render(), file=sys.stderr)
