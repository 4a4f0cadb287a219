"""`plc export plcopen --out FILE.xml [PATHS]`: our ST project as a PLCopen TC6 0201 file.

Types become <dataType>s, POUs keep their ST bodies (text as written, comments included), variables
carry their documentation (the comment on their line), and the CONFIGURATION becomes
<instances><configurations>.  OpenPLC Editor and Beremiz open the result; `plc import plcopen` (or
the compiler itself) reads it back to the same declarations and statements.  The output depends only
on the sources (no clock in the header).

Exit codes: 0 written, 1 the sources have errors (nothing written), 2 usage problems.
"""
from __future__ import annotations

import argparse
import copy
import re
import sys
from pathlib import Path

from lxml import etree

from .. import ast as A
from .. import cliargs, portability
from ..cliargs import EXIT_FINDINGS, EXIT_OK, EXIT_USAGE
from ..diagnostics import Diagnostics, Pos
from ..driver import UserError, collect_files, display_name, read_source
from ..parser import parse
from ..project import project_root
from . import editor4xml
from .datatypes import ELEMENTARY
from .xmlfile import NS, XHTML, XmlError, children, parse_bytes, path

FIXED_TIME = "2000-01-01T00:00:00"
SECTION_LIST = {"VAR_INPUT": "inputVars", "VAR_OUTPUT": "outputVars", "VAR_IN_OUT": "inOutVars",
                "VAR_EXTERNAL": "externalVars", "VAR_GLOBAL": "globalVars", "VAR": "localVars",
                "VAR_TEMP": "tempVars"}
POU_TYPE = {"FUNCTION": "function", "FUNCTION_BLOCK": "functionBlock", "PROGRAM": "program"}
UNSIGNED = {"USINT", "UINT", "UDINT", "ULINT", "BYTE", "WORD", "DWORD", "LWORD"}
TOKENS = re.compile(r"\(\*.*?\*\)|/\*.*?\*/|//[^\n]*|'(?:\$.|[^'])*'|\"(?:\$.|[^\"])*\"|\bEND_VAR\b|"
                    r"\bSTRUCT\b|\bEND_STRUCT\b|[;()\[\]]|:=", re.S | re.I)


NSMAP = {None: NS, "xhtml": XHTML, "xsd": "http://www.w3.org/2001/XMLSchema"}


def E(tag: str, parent=None, **attrs):
    el = etree.Element(f"{{{NS}}}{tag}", nsmap=NSMAP) if parent is None else \
        etree.SubElement(parent, f"{{{NS}}}{tag}")
    for k, v in attrs.items():
        el.set(k, str(v))
    return el


class Source:
    """One ST file: its text and helpers to cut declarations and bodies out of it."""

    def __init__(self, name: str, text: str):
        self.name = name
        self.text = text
        self.starts = [0] + [m.end() for m in re.finditer(r"\n", text)]

    def offset(self, pos) -> int:
        return self.starts[pos.line - 1] + pos.col - 1

    def decl_init(self, pos) -> str | None:
        """The initial value written after the top-level ':=' of the declaration starting at pos."""
        depth = 0
        init_at = None
        for m in TOKENS.finditer(self.text, self.offset(pos)):
            tok = m.group(0).upper()
            if tok.startswith(("(*", "/*", "//", "'", '"')):
                continue
            if tok in ("(", "[", "STRUCT"):
                depth += 1
            elif tok in (")", "]", "END_STRUCT"):
                depth -= 1
            elif tok == ":=" and depth == 0 and init_at is None:
                init_at = m.end()
            elif tok == ";" and depth == 0:
                return self.text[init_at:m.start()].strip() if init_at is not None else None
        return None

    def line_comment(self, pos) -> str:
        """The (* comment *) after the declaration on its own line."""
        line = self.text[self.starts[pos.line - 1]:].split("\n", 1)[0]
        m = re.search(r";\s*\(\*(.*?)\*\)\s*$", line)
        return m.group(1).strip() if m else ""

    def leading_comment(self, pos) -> str:
        """The (* comment *) written right above the declaration at pos (only blank space between)."""
        before = self.text[:self.starts[pos.line - 1]].rstrip()
        if not before.endswith("*)"):
            return ""
        start = before.rfind("(*")
        if start < 0 or "*)" in before[start:-2]:
            return ""
        line_start = before.rfind("\n", 0, start) + 1
        if before[line_start:start].strip():      # the comment ends a line of code: not this declaration's
            return ""
        return _unindent(before[start + 2:-2])

    def body(self, pou: A.Pou) -> str:
        """The statements of a POU as written: after its last END_VAR (or its header line) up to END_<kind>."""
        start = self.offset(pou.pos)
        end = self.offset(pou.end_pos) if pou.end_pos else len(self.text)
        after = None
        for m in TOKENS.finditer(self.text, start, end):
            if m.group(0).upper() == "END_VAR":
                after = m.end()
        if after is None:
            nl = self.text.find("\n", start, end)
            after = nl + 1 if nl >= 0 else end
        return self.text[after:end].strip("\n") + "\n"


def _unindent(text: str) -> str:
    lines = text.strip("\n").split("\n")
    first, rest = lines[0].strip(), [ln for ln in lines[1:]]
    margin = min((len(ln) - len(ln.lstrip()) for ln in rest if ln.strip()), default=0)
    return "\n".join([first, *(ln[margin:] for ln in rest)]).strip()


def expr_text(e) -> str:
    if isinstance(e, A.IntLit):
        return f"{e.prefix}#{e.value}" if e.prefix else str(e.value)
    if isinstance(e, A.Name):
        return e.text or e.name
    if isinstance(e, A.Unary):
        return f"{e.op}{expr_text(e.operand)}"
    raise UserError(f"{e.pos}: only literal numbers and constants can be array or subrange bounds here")


def type_xml(spec, parent, src: Source) -> None:
    if isinstance(spec, A.TypeRef):
        up = spec.name.upper()
        if up in ("STRING", "WSTRING"):
            el = E(up.lower(), parent)
            if spec.length is not None:
                el.set("length", expr_text(spec.length))
        elif up in ELEMENTARY:
            E(up, parent)
        else:
            E("derived", parent, name=spec.text or spec.name)
    elif isinstance(spec, A.EnumSpec):
        values = E("values", E("enum", parent))
        for (_name, _pos, value), text in zip(spec.values, spec.texts or [v[0] for v in spec.values], strict=True):
            if value is not None:
                raise UserError(f"{spec.pos}: enum values with explicit numbers cannot be exported")
            E("value", values, name=text)
    elif isinstance(spec, A.SubrangeSpec):
        kind = "subrangeUnsigned" if spec.base.name.upper() in UNSIGNED else "subrangeSigned"
        el = E(kind, parent)
        E("range", el, lower=expr_text(spec.lo), upper=expr_text(spec.hi))
        type_xml(spec.base, E("baseType", el), src)
    elif isinstance(spec, A.ArraySpec):
        el = E("array", parent)
        for lo, hi in spec.dims:
            E("dimension", el, lower=expr_text(lo), upper=expr_text(hi))
        type_xml(spec.elem, E("baseType", el), src)
    elif isinstance(spec, A.StructSpec):
        el = E("struct", parent)
        for m in spec.members:
            v = E("variable", el, name=m.text or m.name)
            type_xml(m.spec, E("type", v), src)
            init = src.decl_init(m.pos)
            if init:
                E("simpleValue", E("initialValue", v), value=init)
    else:
        raise UserError(f"{spec.pos}: this type cannot be written to PLCopen XML")


def documentation(parent, text: str) -> None:
    if text:
        doc = E("documentation", parent)
        p = etree.SubElement(doc, f"{{{XHTML}}}p")
        p.text = etree.CDATA(text)


def var_lists(parent, blocks: list[A.VarBlock], src: Source, sections=None) -> None:
    for b in blocks:
        tag = SECTION_LIST.get(b.section)
        if tag is None or (sections and b.section not in sections):
            raise UserError(f"{b.pos}: {b.section} cannot be written to PLCopen XML here")
        attrs = {}
        if b.constant:
            attrs["constant"] = "true"
        if b.retain:
            attrs["retain"] = "true"
        vl = E(tag, parent, **attrs)
        for d in b.decls:
            v = E("variable", vl, name=d.text or d.name)
            if d.location is not None:
                v.set("address", d.location.text)
            type_xml(d.spec, E("type", v), src)
            init = src.decl_init(d.pos) if d.init is not None else None
            if init:
                E("simpleValue", E("initialValue", v), value=init)
            documentation(v, src.line_comment(d.pos))


def export(paths: list[str], diags: Diagnostics) -> bytes | None:
    """The PLCopen document for the ST files under `paths`; None when they have parse errors."""
    files = [f for f in collect_files(paths) if f.suffix.lower() == ".st"]
    xml_roots = []
    for f in collect_files(paths):
        if f.suffix.lower() == ".xml":       # PLCopen sources go across as they are (a ladder stays ladder)
            try:
                xml_roots.append(parse_bytes(f.read_bytes()))
            except XmlError as e:
                diags.error(Pos(display_name(f), e.line, e.col or 1), str(e))
    parsed = []
    for f in files:
        name = display_name(f)
        text = read_source(f)
        tree = parse(text, name, diags)
        portability.warn(tree.facts, diags)  # what the lexer and the parser found, as a build would report it
        parsed.append((Source(name, text), tree))
    if diags.has_errors():
        return None
    root = E("project")
    E("fileHeader", root, companyName="atc-plc", productName="atc-plc", productVersion="1",
      creationDateTime=FIXED_TIME)
    ch = E("contentHeader", root, name="atc-plc", modificationDateTime=FIXED_TIME)
    ci = E("coordinateInfo", ch)
    for lang in ("fbd", "ld", "sfc"):
        E("scaling", E(lang, ci), x="10", y="10")
    types = E("types", root)
    data_types = E("dataTypes", types)
    pous = E("pous", types)
    configs = []
    for src, tree in parsed:
        for item in tree.items:
            if isinstance(item, A.TypeBlock):
                for k, td in enumerate(item.decls):
                    dt = E("dataType", data_types, name=td.text or td.name)
                    type_xml(td.spec, E("baseType", dt), src)
                    init = src.decl_init(td.pos) if td.init is not None else None
                    if init:
                        E("simpleValue", E("initialValue", dt), value=init)
                    if k == 0:
                        documentation(dt, src.leading_comment(item.pos))
            elif isinstance(item, A.Pou):
                p = E("pou", pous, name=item.text or item.name, pouType=POU_TYPE[item.kind])
                iface = E("interface", p)
                if item.ret is not None:
                    type_xml(item.ret, E("returnType", iface), src)
                var_lists(iface, item.blocks, src)
                if not len(iface):
                    p.remove(iface)
                xp = etree.SubElement(E("ST", E("body", p)), f"{{{XHTML}}}p")
                xp.text = etree.CDATA(src.body(item))
                documentation(p, src.leading_comment(item.pos))
            elif isinstance(item, A.Configuration):
                configs.append((src, item))
            else:
                diags.error(item.pos, "global VAR outside a CONFIGURATION cannot be exported")
    for x in xml_roots:
        for holder, tag in ((data_types, "dataTypes"), (pous, "pous")):
            found = path(x, "types", tag)
            for el in children(found) if found is not None else []:
                holder.append(copy.deepcopy(el))
        found = path(x, "instances", "configurations")
        for el in children(found) if found is not None else []:
            configs.append((None, el))
    holder = E("configurations", E("instances", root))      # required by the schema, even when empty
    if configs:
        for src, c in configs:
            if src is None:
                holder.append(copy.deepcopy(c))
                continue
            ce = E("configuration", holder, name=c.text or c.name)
            for r in c.resources:
                re_ = E("resource", ce, name=r.text or r.name)
                tasks = {}
                resource_level = []
                for t in r.tasks:
                    te = E("task", re_, name=t.text or t.name, priority=expr_text(t.priority) if t.priority else "0")
                    if t.interval is not None:
                        te.set("interval", src.text[src.offset(t.interval.pos):].split(",")[0].split(")")[0].strip())
                    if t.single is not None:
                        te.set("single", expr_text(t.single))
                    tasks[t.name] = te
                for pi in r.programs:
                    if pi.args:
                        diags.error(pi.pos, "program instances with arguments cannot be exported")
                    if pi.task in tasks:
                        E("pouInstance", tasks[pi.task], name=pi.text or pi.name, typeName=pi.type_text)
                    else:
                        resource_level.append(pi)
                var_lists(re_, r.globals, src, {"VAR_GLOBAL"})       # the schema's order: tasks, globals, instances
                for pi in resource_level:
                    E("pouInstance", re_, name=pi.text or pi.name, typeName=pi.type_text)
            var_lists(ce, c.globals, src, {"VAR_GLOBAL"})
    if diags.has_errors():
        return None
    return etree.tostring(root, xml_declaration=True, encoding="utf-8", pretty_print=True)


def declaration_positions(paths: list[str]) -> dict[str, Pos]:
    """Upper-case name -> source position of every type, POU, configuration, resource and task in the ST
    sources (for the notes and errors of --for openplc-editor)."""
    out: dict[str, Pos] = {}
    for f in collect_files(paths):
        if f.suffix.lower() != ".st":
            continue
        for item in parse(read_source(f), display_name(f), Diagnostics()).items:
            if isinstance(item, A.TypeBlock):
                for td in item.decls:
                    out.setdefault(td.name.upper(), td.pos)
            elif isinstance(item, A.Pou):
                out.setdefault(item.name.upper(), item.pos)
            elif isinstance(item, A.Configuration):
                out.setdefault(item.name.upper(), item.pos)
                for r in item.resources:
                    out.setdefault(r.name.upper(), r.pos)
                    for t in r.tasks:
                        out.setdefault(t.name.upper(), t.pos)
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="plc export", description="Write the ST project in another format.")
    sub = p.add_subparsers(dest="format", metavar="{plcopen}")
    sub.required = True
    o = sub.add_parser("plcopen", help="PLCopen TC6 XML for OpenPLC Editor and Beremiz",
                       description="Write the ST sources (types, POUs with ST bodies, configuration) as one "
                                   "PLCopen TC6 0201 XML project. Exit 0 written, 1 source errors, 2 usage.")
    o.add_argument("paths", nargs="*", metavar="PATH", help=".st files or directories (default: st_src/)")
    o.add_argument("--out", required=True, type=Path, metavar="FILE.xml", help="the file to write")
    o.add_argument("--for", dest="reader", choices=["openplc-editor"], metavar="openplc-editor",
                   help="shape the file for OpenPLC Editor v4's PLCopen import (one variable list of each kind "
                        "per POU, CONSTANT/RETAIN dropped with a note, global variables at the configuration); "
                        "exit 1 when it would still lose something (docs/openplc-editor.md)")
    o.add_argument("-q", "--quiet", action="store_true", help="print errors only")
    return p


def main(argv: list[str]) -> int:
    args, code = cliargs.parse(build_parser(), argv)
    if args is None:
        return code
    root = project_root()
    paths = args.paths or ([str(root / "st_src")] if root else [])
    if not paths:
        print("plc export: error: no sources given and no project st_src/ found from here", file=sys.stderr)
        return EXIT_USAGE
    diags = Diagnostics()
    try:
        data = export(paths, diags)
    except UserError as e:
        print(f"plc export: error: {e}", file=sys.stderr)
        return EXIT_FINDINGS
    for d in diags.sorted():
        print(d.render(), file=sys.stderr)
    if data is None:
        print("plc export: nothing written", file=sys.stderr)
        return EXIT_FINDINGS
    if args.reader == "openplc-editor":
        data, notes, lost = editor4xml.for_editor(data)
        where = declaration_positions(paths) if notes or lost else {}
        for n in notes if not args.quiet else []:
            pos = where.get(editor4xml.declaration_of(n).upper())
            print(f"{pos}: note: {n.message}" if pos else f"plc export: note: {n.message}", file=sys.stderr)
        for p in lost:
            pos = where.get(editor4xml.declaration_of(p).upper())
            print(f"{pos}: error: {p.message}" if pos else f"plc export: error: {p.message}", file=sys.stderr)
        if lost:
            print("plc export: nothing written (Editor v4 would lose what is listed above)", file=sys.stderr)
            return EXIT_FINDINGS
    try:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_bytes(data)
    except OSError as e:
        print(f"plc export: error: cannot write {args.out}: {e.strerror or e}", file=sys.stderr)
        return EXIT_USAGE
    if not args.quiet:
        print(f"plc export: wrote {args.out}", file=sys.stderr)
    return EXIT_OK
