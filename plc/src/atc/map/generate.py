"""Every generated file of the register map, the drift check, and the generated ST compiled as a check.

`outputs()` returns {path relative to the repository: text}; writing them is byte-for-byte reproducible
(no time stamps, fixed order, '\\n' line ends).  The PROGRAM file is not generated whole: only the region
between its BEGIN/END GENERATED markers is replaced.
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass
from pathlib import Path

from plc.diagnostics import Diagnostics, Pos
from plc.driver import compile_sources

from . import gen_doc, gen_linuxcnc, gen_st, gen_tags, gen_v4
from .check import check
from .enums import EnumType, st_facts
from .model import RegisterMap, load

TAGS_CSV = "hmi_tags/atc_tags.csv"
TAGS_JSON = "hmi_tags/atc_tags.json"
MB2HAL_INI = "configs/linuxcnc/atc_mb2hal.ini"
IOV2_HAL = "configs/linuxcnc/atc_iov2.hal"
IO_HAL = "configs/linuxcnc/atc_io.hal"
MAP_DOC = "docs/register-map.md"


@dataclass
class Loaded:
    rmap: RegisterMap
    enums: dict[str, EnumType]


def load_and_check(map_path: Path, diags: Diagnostics) -> Loaded | None:
    """Load the map, read the ST enums, run every check (not drift); None if the map could not be read."""
    rmap = load(map_path, diags)
    if rmap is None:
        return None
    facts = st_facts(rmap.root / "st_src", rmap.root)
    check(rmap, facts, diags)
    gen_v4.check(rmap, diags)
    _check_program_file(rmap, diags)
    if not diags.has_errors():
        check_generated_st(rmap, diags)
    return Loaded(rmap, facts.enums)


def check_with_machine(map_path: Path, described: Path, diags: Diagnostics) -> None:
    """The map's checks with the carousel lines of another machine file (`plc machine check --config FILE`):
    what a run of that machine checks of the map, without the generated files (those are its workspace's)."""
    rmap = load(map_path, diags, described=described)
    if rmap is not None:
        check(rmap, st_facts(rmap.root / "st_src", rmap.root), diags)


def _check_program_file(rmap: RegisterMap, diags: Diagnostics) -> None:
    path = rmap.root / rmap.program_file
    where = rmap.section_pos("map", "program_file")
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        diags.error(where, f"[map] program_file {rmap.program_file}: cannot read ({exc.strerror or exc})")
        return
    problem = gen_st.marker_problem(text)
    if problem:
        diags.error(Pos(rmap.program_file, 1, 1), f"{rmap.program_file} {problem}")


def check_generated_st(rmap: RegisterMap, diags: Diagnostics) -> None:
    """Compile the generated region inside a stub PROGRAM with our compiler (--target openplc): any error or
    portability warning is reported as an error, since the lead's PROGRAM must compile with MATIEC too."""

    head = "PROGRAM MapRegionCheck\n"
    body = gen_st.region(rmap)
    stub = (head + body + "VAR\n    regionCheckDone : BOOL;\nEND_VAR\nregionCheckDone := TRUE;\n"
            "END_PROGRAM\nCONFIGURATION Config0\n    RESOURCE Res0 ON PLC\n"
            "        TASK MainTask(INTERVAL := T#4ms, PRIORITY := 0);\n"
            "        PROGRAM MapCheck WITH MainTask : MapRegionCheck;\n    END_RESOURCE\nEND_CONFIGURATION\n")
    name = "<generated region>"
    result = compile_sources([], target="openplc", generate=False, extra_texts=[(name, stub)])
    begin = _marker_line(rmap)
    for d in result.diags.sorted():
        if d.pos.file != name:
            continue
        line = begin + d.pos.line - 1 if begin else 0
        diags.error(Pos(rmap.program_file, line, d.pos.col), f"generated declarations (as generated): "
                    f"{d.message}", d.hint)


def _marker_line(rmap: RegisterMap) -> int:
    try:
        lines = (rmap.root / rmap.program_file).read_text(encoding="utf-8").splitlines()
    except OSError:
        return 0
    return next((i for i, line in enumerate(lines, start=1) if line.strip() == gen_st.BEGIN), 0)


def outputs(loaded: Loaded) -> dict[str, str]:
    rmap, enums = loaded.rmap, loaded.enums
    files = {
        TAGS_CSV: gen_tags.tags_csv(rmap, enums),
        TAGS_JSON: gen_tags.tags_json(rmap, enums),
        MB2HAL_INI: gen_linuxcnc.mb2hal_ini(rmap),
        IOV2_HAL: gen_linuxcnc.hal_file(rmap, "iov2"),
        IO_HAL: gen_linuxcnc.hal_file(rmap, "io"),
        MAP_DOC: gen_doc.register_map_md(rmap, enums),
        gen_v4.SLAVE_JSON: gen_v4.modbus_slave_json(rmap),
    }
    program = rmap.root / rmap.program_file
    current = program.read_text(encoding="utf-8") if program.is_file() else ""
    spliced = gen_st.splice(current, gen_st.region(rmap))
    if spliced is not None:
        wired = gen_st.splice_wiring(spliced, gen_st.wiring(rmap))
        files[rmap.program_file] = wired if wired is not None else spliced
    return dict(sorted(files.items()))


def drift(loaded: Loaded, diags: Diagnostics, show_diff: bool = True) -> list[str]:
    """Report every generated file that differs from what generate would write; returns their paths."""
    stale = []
    for rel, text in outputs(loaded).items():
        path = loaded.rmap.root / rel
        try:
            current = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            current = None
        except (OSError, UnicodeDecodeError) as exc:
            diags.error(Pos(rel, 0, 0), f"cannot read: {exc}")
            continue
        if current == text:
            continue
        stale.append(rel)
        if current is None:
            diags.error(Pos(rel, 0, 0), "drift: the file does not exist", "run: plc map generate")
            continue
        line = _first_difference(current, text)
        hint = "run: plc map generate"
        if show_diff:
            diff = list(difflib.unified_diff(current.splitlines(), text.splitlines(), f"{rel} (on disk)",
                                             f"{rel} (generated)", lineterm="", n=1))
            hint += "\n" + "\n".join("      " + d for d in diff[:24])
            if len(diff) > 24:
                hint += f"\n      ... {len(diff) - 24} more diff lines"
        diags.error(Pos(rel, line, 1), "drift: differs from what modbus_map generates", hint)
    return stale


def _first_difference(a: str, b: str) -> int:
    for i, (x, y) in enumerate(zip(a.splitlines(), b.splitlines(), strict=False), start=1):
        if x != y:
            return i
    return min(len(a.splitlines()), len(b.splitlines())) + 1


def write(loaded: Loaded) -> list[str]:
    """Write every output whose content changed; returns the paths written."""
    written = []
    for rel, text in outputs(loaded).items():
        path = loaded.rmap.root / rel
        try:
            if path.read_text(encoding="utf-8") == text:
                continue
        except (FileNotFoundError, UnicodeDecodeError):
            pass
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(text, encoding="utf-8", newline="\n")
        tmp.replace(path)
        written.append(rel)
    return written
