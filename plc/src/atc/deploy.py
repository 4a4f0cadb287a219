"""`plc deploy openplc --out FILE.st`: the whole application (ST and PLCopen XML sources) as one ST file for an
OpenPLC runtime upload.

OpenPLC compiles one uploaded .st file with its MATIEC (`iec2c -f -l -p -r -R -a`) against its own library,
so the file holds everything of st_src/ (the library, the generated tables, the application and the
CONFIGURATION Config0 / RESOURCE Res0) and nothing of our test library.  Order: TYPE blocks first, each after
the types it uses, then FUNCTIONs, FUNCTION_BLOCKs, PROGRAMs and the CONFIGURATION last; every item keeps the
comment lines in front of it.  The result is compiled with our compiler for --target openplc and is written
only when it has no error and no portability warning.  The output depends only on the sources.
"""
from __future__ import annotations

import argparse
import re
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from plc import ast as A
from plc import cliargs, portability
from plc.cliargs import EXIT_FINDINGS, EXIT_OK, EXIT_USAGE
from plc.diagnostics import Diagnostics, Pos, SourceSet
from plc.driver import collect_files, compile_sources, display_name, load_user_file
from plc.io_config import MODULE_INPUTS, MODULE_OUTPUTS, OPENPLC_SLAVE_FIRST_BYTE
from plc.parser import parse
from plc.project import add_view_options, project_root

from . import service
from .freshness import problems
from .host.tags import load_map

KIND_ORDER = {"TYPE": 0, "FUNCTION": 1, "FUNCTION_BLOCK": 2, "PROGRAM": 3, "CONFIGURATION": 4}


@dataclass
class Item:
    kind: str                  # TYPE FUNCTION FUNCTION_BLOCK PROGRAM CONFIGURATION (VAR_GLOBAL outside: error)
    names: list[str]           # declared names (upper case)
    uses: set[str]             # type names a TYPE block refers to (upper case)
    text: str                  # source text incl. the comments in front of it
    origin: str                # file:line
    first_line: int = 0        # line of `text`'s first line in its file
    order: int = 0             # position in the input (stable tie-break)
    deps: set[int] = field(default_factory=set)


def _type_refs(spec, out: set[str]) -> None:
    if isinstance(spec, A.TypeRef):
        out.add(spec.name.upper())
    elif isinstance(spec, A.ArraySpec):
        _type_refs(spec.elem, out)
    elif isinstance(spec, A.SubrangeSpec):
        _type_refs(spec.base, out)
    elif isinstance(spec, A.StructSpec):
        for m in spec.members:
            _type_refs(m.spec, out)


def _end_line(lines: list[str], start: int, keyword: str) -> int:
    """1-based line of the first `keyword` at or after line `start` (outside comments), else the last line."""
    depth_text = "\n".join(lines[start - 1:])
    pattern = re.compile(r"\(\*.*?\*\)|\b" + keyword + r"\b", re.DOTALL | re.IGNORECASE)
    for m in pattern.finditer(depth_text):
        if not m.group(0).startswith("(*"):
            return start + depth_text.count("\n", 0, m.start())
    return len(lines)


def split_items(name: str, text: str, diags: Diagnostics) -> list[Item]:
    tree = parse(text, name, diags)
    portability.warn(tree.facts, diags)      # what the lexer and the parser found, as a build would report it
    lines = text.splitlines()
    items: list[Item] = []
    prev_end = 0
    for node in tree.items:
        start = node.pos.line
        if isinstance(node, A.TypeBlock):
            end = _end_line(lines, start, "END_TYPE")
            uses: set[str] = set()
            for d in node.decls:
                _type_refs(d.spec, uses)
            item = Item("TYPE", [d.name.upper() for d in node.decls], uses, "", f"{name}:{start}")
        elif isinstance(node, A.Pou):
            end = node.end_pos.line if node.end_pos else _end_line(lines, start, f"END_{node.kind}")
            item = Item(node.kind, [node.name.upper()], set(), "", f"{name}:{start}")
        elif isinstance(node, A.Configuration):
            end = _end_line(lines, start, "END_CONFIGURATION")
            item = Item("CONFIGURATION", [node.name.upper()], set(), "", f"{name}:{start}")
        else:
            diags.error(node.pos, "only TYPE, POUs and CONFIGURATION can be deployed (global VAR outside a "
                        "CONFIGURATION)")
            continue
        chunk = lines[prev_end:end]
        blank = next((k for k, line in enumerate(chunk) if line), len(chunk))
        item.first_line = prev_end + 1 + blank
        item.text = "\n".join(chunk).strip("\n") + "\n"
        prev_end = end
        items.append(item)
    if items and prev_end < len(lines):
        tail = "\n".join(lines[prev_end:]).strip("\n")
        if tail:
            items[-1].text += tail + "\n"
    return items


def order(items: list[Item]) -> list[Item]:
    """Types first, each after the types it uses (declaration order otherwise), then the POUs by kind."""
    for i, it in enumerate(items):
        it.order = i
    types = [it for it in items if it.kind == "TYPE"]
    owner = {name: i for i, it in enumerate(types) for name in it.names}
    for i, it in enumerate(types):
        it.deps = {owner[u] for u in it.uses if u in owner and owner[u] != i}
    done: list[int] = []
    placed: set[int] = set()
    visiting: set[int] = set()

    def visit(i: int) -> None:
        if i in placed or i in visiting:
            return              # a cycle cannot happen between valid types; the compiler reports it
        visiting.add(i)
        for d in sorted(types[i].deps):
            visit(d)
        visiting.discard(i)
        placed.add(i)
        done.append(i)

    for i in range(len(types)):
        visit(i)
    pous = sorted((it for it in items if it.kind != "TYPE"), key=lambda it: (KIND_ORDER[it.kind], it.order))
    return [types[i] for i in done] + pous


def bundle(src_dirs: list[Path], diags: Diagnostics) -> tuple[str, list[str]]:
    """The deploy text and the list of source files it holds."""
    files = collect_files([str(d) for d in src_dirs])
    items: list[Item] = []
    names: list[str] = []
    for path in files:
        names.append(display_name(path))
        name, text, tr = load_user_file(path, diags, SourceSet())
        if text is None:
            continue
        found = split_items(name, text, diags)
        if tr is not None:          # a PLCopen project: name the XML line the declaration comes from
            for it in found:
                o = tr.origin(int(it.origin.rsplit(":", 1)[1]))
                it.origin = f"{tr.xml_name}:{o.line}" if o is not None else tr.xml_name
            tr.remap(diags)
        items.extend(found)
    ordered = order(items)
    configs = [it for it in ordered if it.kind == "CONFIGURATION"]
    if len(configs) != 1:
        diags.error(diags_pos(names), f"exactly one CONFIGURATION is needed (found {len(configs)})")
    head = ["(* atc-plc for the OpenPLC runtime: generated by `plc deploy openplc` - do not edit; regenerate.",
            "   Upload this one file in OpenPLC's Programs page. It holds every POU and TYPE of the ST sources (types",
            "   first, each after the types it uses), the application and CONFIGURATION Config0 / RESOURCE Res0, and",
            "   no test code. The register map is modbus_map/map.toml (docs/register-map.md).",
            f"   {len(names)} source files, {len(ordered)} declarations. *)"]
    body = []
    for it in ordered:
        body.append(f"(* ---- from {it.origin} *)")
        body.append(it.text.rstrip("\n"))
        body.append("")
    return "\n".join(head) + "\n\n" + "\n".join(body), names


def diags_pos(names: list[str]):
    return Pos(names[0] if names else "<deploy>", 0, 0)


def check_bundle(text: str, diags: Diagnostics) -> tuple[int, int]:
    """Compile the bundle alone for OpenPLC; every error and portability warning goes to diags."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "atc_openplc.st"
        path.write_text(text, encoding="utf-8")
        result = compile_sources([path], target="openplc", generate=True)
        for d in result.diags.sorted():
            if d.pos.file.startswith("<plc>"):
                continue
            where = d.pos.__class__("<deploy>", d.pos.line, d.pos.col)
            if d.severity == "error":
                diags.error(where, d.message, d.hint)
            elif d.severity == "warning":
                diags.warning(where, d.message, d.hint)
        return len(result.diags.errors), len(result.diags.warnings)


def slave_device_locations(root: Path) -> dict[str, str]:
    """Signal name -> its %IX/%QX on OpenPLC when the machine's I/O module is an OpenPLC slave device: the module
    layout of io_config (inputs 0..31, coils 16..23 of the map, carousel lines from the machine description
    included) moved to %IX100.0.. / %QX100.0.."""
    out = {}
    for sig in load_map(root / "modbus_map" / "map.toml").signals:
        a = sig.address
        if sig.direction == "input" and sig.table == "discrete_input" and MODULE_INPUTS[0] <= a < sum(MODULE_INPUTS):
            k, prefix = a - MODULE_INPUTS[0], "%IX"
        elif sig.direction == "output" and sig.table == "coil" and MODULE_OUTPUTS[0] <= a < sum(MODULE_OUTPUTS):
            k, prefix = a - MODULE_OUTPUTS[0], "%QX"
        else:
            continue
        out[sig.name] = f"{prefix}{OPENPLC_SLAVE_FIRST_BYTE + k // 8}.{k % 8}"
    return out


def relocate(text: str, locations: dict[str, str]) -> tuple[str, list[str]]:
    """Move the located declarations `Name AT %IXa.b` of the bundle to `locations`; names not found are returned."""
    missing = []
    for name, where in locations.items():
        text, n = re.subn(rf"(\b{re.escape(name)}\s+AT\s+)%[IQ]X\d+\.\d", rf"\g<1>{where}", text, flags=re.I)
        if n != 1:
            missing.append(name)
    return text, missing


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="plc deploy", description="Bundle the application for another runtime "
                                "(openplc), or install and upgrade our soft-PLC as a systemd service (service, "
                                "upgrade, rollback). Exit status: 0 done, 1 findings (errors in the program, "
                                "an upgrade refused), 2 usage or environment problems.")
    sub = p.add_subparsers(dest="target", metavar="{openplc,service,upgrade,rollback}")
    sub.required = True
    o = sub.add_parser("openplc", help="one self-contained ST file for an OpenPLC runtime upload",
                       description="Write st_src/ (library, generated tables, application, CONFIGURATION) as one "
                                   "ST file an OpenPLC runtime accepts as an upload, checked with --target openplc.")
    o.add_argument("--out", required=True, type=Path, metavar="FILE.st", help="the file to write")
    o.add_argument("--src", type=Path, action="append", metavar="DIR",
                   help="ST source directory (default: st_src/ of the project; repeatable)")
    o.add_argument("--slave-devices", action="store_true",
                   help="place the machine's sensors and actuators where OpenPLC's slave devices put them: the "
                        "I/O module's discrete inputs 0-31 at %%IX100.0-%%IX103.7, its coils 0-7 at "
                        "%%QX100.0-%%QX100.7 (the module of `plc run --io modbus` serves both runtimes)")
    o.add_argument("-q", "--quiet", action="store_true", help="print errors only")
    add_view_options(o)
    service.add_parsers(sub)
    return p


def main(argv: list[str]) -> int:
    parser = build_parser()
    args, code = cliargs.parse(parser, argv)
    if args is None:
        return code
    if args.target != "openplc":
        try:
            args.name = service.service_name(args)
            return args.func(args)
        except service.DeployError as exc:
            print(f"plc deploy: error: {exc}", file=sys.stderr)
            return EXIT_FINDINGS if "does not compile" in str(exc) else EXIT_USAGE
    root = project_root()
    src = args.src or ([root / "st_src"] if root else [])
    if not src or not all(d.is_dir() for d in src):
        print("plc deploy: error: no ST source directory (give --src DIR or run inside the project)",
              file=sys.stderr)
        return EXIT_USAGE
    if root is not None and not args.src:
        stale = problems(root)          # machine description, register map and sequences alike
        if stale:
            for line in stale:
                print(f"plc deploy: error: {line}", file=sys.stderr)
            return EXIT_FINDINGS
    diags = Diagnostics()
    text, names = bundle(src, diags)
    if args.slave_devices:
        if root is None:
            print("plc deploy: error: --slave-devices needs the project's modbus_map/map.toml (run inside the "
                  "project)", file=sys.stderr)
            return EXIT_USAGE
        text, missing = relocate(text, slave_device_locations(root))
        if missing:
            print(f"plc deploy: error: --slave-devices: no located declaration of {', '.join(missing)} in the "
                  "sources (regenerate them: plc map generate)", file=sys.stderr)
            return EXIT_FINDINGS
        text = text.replace("(* atc-plc for the OpenPLC runtime:", "(* atc-plc for the OpenPLC runtime, machine I/O "
                            "on slave devices (%IX100.0.., %QX100.0..):", 1)
    n_err, n_warn = (0, 0)
    if not diags.has_errors():
        n_err, n_warn = check_bundle(text, diags)
    for d in diags.sorted():
        if not args.quiet or d.severity == "error":
            print(d.render(), file=sys.stderr)
    if diags.has_errors() or diags.warnings:
        print(f"plc deploy: nothing written: {len(diags.errors)} error(s), {len(diags.warnings)} warning(s) "
              "(OpenPLC's MATIEC would reject or mishandle what our compiler warns about)", file=sys.stderr)
        return EXIT_FINDINGS
    try:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.out.with_name(args.out.name + ".tmp")
        tmp.write_text(text, encoding="utf-8", newline="\n")
        tmp.replace(args.out)
    except OSError as exc:
        print(f"plc deploy: error: cannot write {args.out}: {exc.strerror or exc}", file=sys.stderr)
        return EXIT_USAGE
    if not args.quiet:
        print(f"plc deploy: wrote {args.out} ({len(names)} source files, {text.count(chr(10))} lines), checked "
              "for OpenPLC: 0 errors, 0 warnings", file=sys.stderr)
    return EXIT_OK
