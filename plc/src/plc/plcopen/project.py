"""A PLCopen project as ST units (types, POUs, configuration), every line tagged with where it came from.

ST bodies are copied as they are; LD and FBD bodies go through netst.  Each unit is one declaration
(one TYPE, one POU or the CONFIGURATION), so `plc import plcopen` can write one file per unit and the
compiler reads them all as one text with a line map back into the XML.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field

from .. import ast as A
from ..diagnostics import Diagnostics
from ..parser import parse
from ..resources import STANDARD_FBS
from ..stdfuncs import STD_FUNCS
from .datatypes import TypeError_, initial_value, type_text
from .graph import GraphError
from .netst import STD_RESULT_TYPE, Context, Sig, translate_body
from .wiretypes import SAME_AS_OUT
from .xmlfile import child, children, flag, line_of, local, path, text_of, text_start

POU_KINDS = {"function": "FUNCTION", "functionBlock": "FUNCTION_BLOCK", "program": "PROGRAM"}
VAR_SECTIONS = [("inputVars", "VAR_INPUT"), ("outputVars", "VAR_OUTPUT"), ("inOutVars", "VAR_IN_OUT"),
                ("externalVars", "VAR_EXTERNAL"), ("globalVars", "VAR_GLOBAL"), ("localVars", "VAR"),
                ("tempVars", "VAR_TEMP")]


@dataclass(frozen=True)
class Origin:
    """Where a generated ST line comes from: XML line, column shift (ST bodies), POU and element."""
    line: int
    col_shift: int = 0
    pou: str = ""
    local_id: int | None = None
    exact: bool = False       # the ST text is the XML text (an ST body): columns map one to one
    spans: tuple = ()         # (first col, end col, localId, XML line) of the parts other elements wrote
    variable: str = ""        # the interface or global variable a declaration line declares

    def element_at(self, col: int) -> tuple[int | None, int]:
        """localId and XML line of the innermost element whose text covers 1-based column col."""
        inside = [s for s in self.spans if s[0] < col <= s[1]]
        if not inside:
            return self.local_id, self.line
        a, b, lid, line = min(inside, key=lambda s: s[1] - s[0])
        return lid, line


@dataclass
class Unit:
    kind: str                 # TYPE FUNCTION FUNCTION_BLOCK PROGRAM CONFIGURATION
    name: str
    lines: list[tuple[str, Origin]] = field(default_factory=list)
    language: str = "ST"
    networks: int = 0

    def add(self, text: str, origin: Origin) -> None:
        for part in text.split("\n"):
            self.lines.append((part, origin))


class ProjectError(Exception):
    def __init__(self, message: str, line: int, pou: str = "", local_id: int | None = None):
        super().__init__(message)
        self.line = line
        self.pou = pou
        self.local_id = local_id


def comment(text: str) -> str:
    """Text made safe inside (* *) (MATIEC does not nest comments)."""
    return text.replace("(*", "( *").replace("*)", "* )").strip()


@functools.lru_cache(maxsize=1)
def standard_fb_sigs() -> dict[str, Sig]:
    """Pins of the standard function blocks, read from the compiler's own standard_fbs.st."""
    tree = parse(STANDARD_FBS.read_text(encoding="utf-8"), "<plc>/standard_fbs.st", Diagnostics())
    out = {}
    for item in tree.items:
        if isinstance(item, A.Pou) and item.kind == "FUNCTION_BLOCK":
            s = Sig("FUNCTION_BLOCK")
            for d in item.decls():
                tname = d.spec.name if isinstance(d.spec, A.TypeRef) else ""
                if d.section == "VAR_INPUT":
                    s.inputs[d.name.upper()] = tname
                elif d.section == "VAR_OUTPUT":
                    s.outputs[d.name.upper()] = tname
            out[item.name.upper()] = s
    return out


def standard_function_sigs() -> dict[str, Sig]:
    return {name: Sig("STD", std_kind=f.kind, inputs={p: "" for p in f.params}, outputs={"OUT": ""})
            for name, f in STD_FUNCS.items() if f.kind in STD_RESULT_TYPE or f.kind in SAME_AS_OUT}


class ProjectReader:
    def __init__(self, root, raw: bytes):
        self.root = root
        self.raw = raw
        self.units: list[Unit] = []
        self.sigs: dict[str, Sig] = {**standard_function_sigs(), **standard_fb_sigs()}
        self.global_types: dict[str, str] = {}
        self.type_names: set[str] = set()
        self.warnings: list[tuple[str, int, str, int | None]] = []    # message, XML line, POU, localId
        self.element_lines: dict[int, dict[str, int]] = {}              # body -> localId -> XML line
        self.errors: list[ProjectError] = []

    # ----------------------------------------------------------------- project --
    def read(self) -> list[Unit]:
        types = path(self.root, "types")
        data_types = children(child(types, "dataTypes"), "dataType") if types is not None and \
            child(types, "dataTypes") is not None else []
        pous = children(child(types, "pous"), "pou") if types is not None and child(types, "pous") is not None \
            else []
        configs = children(path(self.root, "instances", "configurations"), "configuration") \
            if path(self.root, "instances", "configurations") is not None else []
        for dt in data_types:
            self.type_names.add((dt.get("name") or "").upper())
        for p in list(pous):
            try:
                self.signature(p)
            except ProjectError as e:
                self.errors.append(e)
                pous.remove(p)
        for c in configs:
            for holder in [c, *children(c, "resource")]:
                for gv in children(holder, "globalVars"):
                    for v in children(gv, "variable"):
                        t = child(v, "type")
                        if t is not None:
                            self.global_types[(v.get("name") or "").upper()] = self.safe_type(t, "")
        # every declaration is read even after one failed, so one run reports every problem of the file
        for reader, items in ((self.data_type, data_types), (self.pou, pous), (self.configuration, configs)):
            for item in items:
                try:
                    self.units.append(reader(item))
                except ProjectError as e:
                    self.errors.append(e)
        return self.units

    def safe_type(self, holder, pou: str) -> str:
        try:
            return type_text(holder)
        except TypeError_ as e:
            raise ProjectError(str(e), e.line, pou) from None

    def signature(self, p) -> None:
        name = p.get("name") or ""
        kind = POU_KINDS.get(p.get("pouType") or "", "")
        if not name or not kind:
            raise ProjectError(f"<pou> needs a name and a pouType (function, functionBlock, program); got "
                               f"name={name!r} pouType={p.get('pouType')!r}", line_of(p), name)
        s = Sig(kind)
        iface = child(p, "interface")
        if iface is not None:
            rt = child(iface, "returnType")
            if rt is not None:
                s.ret = self.safe_type(rt, name)
            for section, target in (("inputVars", s.inputs), ("outputVars", s.outputs), ("inOutVars", s.inputs)):
                for vl in children(iface, section):
                    for v in children(vl, "variable"):
                        t = child(v, "type")
                        target[(v.get("name") or "").upper()] = self.safe_type(t, name) if t is not None else ""
        self.sigs[name.upper()] = s
        self.type_names.add(name.upper())

    # ------------------------------------------------------------------- types --
    def data_type(self, dt) -> Unit:
        name = dt.get("name") or ""
        unit = Unit("TYPE", name)
        here = Origin(line_of(dt), pou=name)
        base = child(dt, "baseType")
        if not name or base is None:
            raise ProjectError("<dataType> needs a name and a <baseType>", line_of(dt), name)
        doc = text_of(child(dt, "documentation")).strip()
        if doc:
            unit.add(f"(* {comment(doc)} *)", here)
        init = initial_value(child(dt, "initialValue"))
        spec = self.safe_type(base, name)
        unit.add("TYPE", here)
        unit.add(f"    {name} : {spec}" + (f" := {init}" if init else "") + ";", here)
        unit.add("END_TYPE", here)
        return unit

    # -------------------------------------------------------------------- POUs --
    def pou(self, p) -> Unit:
        name = p.get("name")
        kind = POU_KINDS[p.get("pouType")]
        here = Origin(line_of(p), pou=name)
        iface = child(p, "interface")
        body_holder = child(p, "body")
        body = children(body_holder)[0] if body_holder is not None and children(body_holder) else None
        language = local(body) if body is not None else ""
        if body is None:
            raise ProjectError(f"POU {name} has no <body>", line_of(p), name)
        if language in ("SFC", "IL"):
            raise ProjectError(f"POU {name}: {language} bodies are not supported (translate it to ST, LD or FBD in "
                               "the editor)", line_of(body), name)
        if language not in ("ST", "LD", "FBD"):
            raise ProjectError(f"POU {name}: unknown body language <{language}>", line_of(body), name)
        unit = Unit(kind, name, language=language)
        doc = text_of(child(p, "documentation")).strip()
        if doc:
            unit.add(f"(* {comment(doc)} *)", here)
        header = f"{kind} {name}"
        if kind == "FUNCTION":
            rt = child(iface, "returnType") if iface is not None else None
            if rt is None:
                raise ProjectError(f"FUNCTION {name} has no <returnType>", line_of(p), name)
            header += f" : {self.safe_type(rt, name)}"
        unit.add(header, here)
        var_types: dict[str, str] = dict(self.global_types)
        taken = set(self.type_names) | set(self.sigs)
        if kind == "FUNCTION":
            var_types[name.upper()] = self.sigs[name.upper()].ret or ""
        if iface is not None:
            for section, keyword in VAR_SECTIONS:
                for vl in children(iface, section):
                    self.var_list(unit, vl, keyword, name, var_types, taken)
            if children(iface, "accessVars"):
                raise ProjectError(f"POU {name}: VAR_ACCESS is not supported", line_of(iface), name)
        if language == "ST":
            self.st_body(unit, body, name)
        else:
            ctx = Context(name, kind, var_types, self.sigs, taken)
            try:
                result = translate_body(body, ctx, language)
            except GraphError as e:
                raise ProjectError(str(e), e.line, name, e.local_id) from None
            except RecursionError:
                # loops are refused before translating (graph.check_loops): this is a chain of elements deeper
                # than the recursive translation goes (some thousands under `plc`, which raises the stack limit)
                raise ProjectError(f"the wiring of this {language} body chains too many elements one after another "
                                   "to translate: split the chain with variables", line_of(body), name) from None
            unit.networks = result.networks
            self.warnings += [(msg, e.line, name, e.id) for msg, e in result.warnings]
            if result.decls:
                unit.add(f"VAR (* generated from the {language} body: power flow shared by several elements, edge "
                         "detectors and block outputs, named after their localId *)", Origin(line_of(body), pou=name))
                width = max(len(d[0]) for d in result.decls)
                for dname, dtype, dcomment, lid in result.decls:
                    where = Origin(self.element_line(body, lid), pou=name, local_id=lid) if lid is not None \
                        else Origin(line_of(body), pou=name)
                    unit.add(f"    {dname.ljust(width)} : {dtype}; (* {comment(dcomment)} *)", where)
                unit.add("END_VAR", Origin(line_of(body), pou=name))
            for ln in result.lines:
                el_line = line_of(body)
                if ln.local_id is not None:
                    el_line = self.element_line(body, ln.local_id)
                spans = tuple((a, b, i, self.element_line(body, i)) for a, b, i in ln.spans)
                unit.add(ln.text, Origin(el_line, pou=name, local_id=ln.local_id, spans=spans))
        unit.add(f"END_{kind}", Origin(line_of(p), pou=name))
        return unit

    def element_line(self, body, local_id: int) -> int:
        lines = self.element_lines.get(id(body))
        if lines is None:
            lines = {el.get("localId"): line_of(el) for el in children(body)}
            self.element_lines[id(body)] = lines
        return lines.get(str(local_id), line_of(body))

    def var_list(self, unit: Unit, vl, keyword: str, pou: str, var_types: dict, taken: set) -> None:
        qual = []
        if flag(vl, "constant"):
            qual.append("CONSTANT")
        if flag(vl, "retain"):
            qual.append("RETAIN")
        if flag(vl, "nonretain"):
            qual.append("NON_RETAIN")
        variables = children(vl, "variable")
        located = [v for v in variables if v.get("address")]
        plain = [v for v in variables if not v.get("address")]
        for group in (plain, located):        # MATIEC rejects a block mixing located and unlocated variables
            if not group:
                continue
            unit.add(" ".join([keyword, *qual]), Origin(line_of(vl), pou=pou))
            for v in group:
                vname = v.get("name") or ""
                t = child(v, "type")
                if not vname or t is None:
                    raise ProjectError("<variable> needs a name and a <type>", line_of(v), pou)
                ttext = self.safe_type(t, pou)
                var_types[vname.upper()] = ttext
                taken.add(vname.upper())
                init = initial_value(child(v, "initialValue"))
                addr = v.get("address")
                doc = text_of(child(v, "documentation")).strip()
                text = f"    {vname}" + (f" AT {addr}" if addr else "") + f" : {ttext}" + \
                    (f" := {init}" if init else "") + ";" + (f" (* {comment(doc)} *)" if doc else "")
                unit.add(text, Origin(line_of(v), pou=pou, variable=vname))
            unit.add("END_VAR", Origin(line_of(vl), pou=pou))

    def st_body(self, unit: Unit, body, pou: str) -> None:
        holder = children(body)[0] if children(body) else body
        text = text_of(holder)
        line, col = text_start(self.raw, holder)
        # keep the first line on its own so columns still match the XML
        for k, part in enumerate(text.split("\n")):
            unit.lines.append((part, Origin(line + k, col - 1 if k == 0 else 0, pou, exact=True)))

    # ----------------------------------------------------------- configuration --
    def configuration(self, c) -> Unit:
        name = c.get("name") or ""
        unit = Unit("CONFIGURATION", name)
        here = Origin(line_of(c), pou=name)
        unit.add(f"CONFIGURATION {name}", here)
        for gv in children(c, "globalVars"):
            self.var_list(unit, gv, "VAR_GLOBAL", name, {}, set())
        for r in children(c, "resource"):
            rh = Origin(line_of(r), pou=name)
            unit.add(f"    RESOURCE {r.get('name')} ON PLC", rh)
            for gv in children(r, "globalVars"):
                sub = Unit("", "")
                self.var_list(sub, gv, "VAR_GLOBAL", name, {}, set())
                for text, o in sub.lines:
                    unit.lines.append(("        " + text, o))
            instances = []
            for t in children(r, "task"):
                parts = []
                if t.get("single"):
                    parts.append(f"SINGLE := {t.get('single')}")
                if t.get("interval"):
                    parts.append(f"INTERVAL := {t.get('interval')}")
                parts.append(f"PRIORITY := {t.get('priority') or '0'}")
                unit.add(f"        TASK {t.get('name')}({', '.join(parts)});", Origin(line_of(t), pou=name))
                for pi in children(t, "pouInstance"):
                    instances.append((pi, t.get("name")))
            for pi in children(r, "pouInstance"):
                instances.append((pi, None))
            for pi, task in instances:
                with_task = f" WITH {task}" if task else ""
                unit.add(f"        PROGRAM {pi.get('name')}{with_task} : {pi.get('typeName')};",
                         Origin(line_of(pi), pou=name))
            unit.add("    END_RESOURCE", rh)
        unit.add("END_CONFIGURATION", here)
        return unit


def read_project(root, raw: bytes) -> tuple[list[Unit], list[ProjectError], list[tuple[str, int, str, int | None]]]:
    """The units of the project, the errors (declarations that could not be read) and the warnings met on the
    way (message, XML line, POU, localId)."""
    reader = ProjectReader(root, raw)
    units = reader.read()
    return units, reader.errors, reader.warnings

