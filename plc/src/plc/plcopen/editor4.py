"""OpenPLC Editor v4 project folders as a source format (docs/openplc-editor.md).

An Editor v4 project is a folder: `project.json` (data types, the configuration with its tasks, program
instances and global variables) and one file per POU under `pous/programs`, `pous/functions` and
`pous/function-blocks`.  A `.st` file is plain ST.  A `.ld` or `.fbd` file is an optional doc comment,
the POU header, its IEC VAR blocks, a JSON body and the END_ keyword; the body holds react-flow nodes
and edges (LD: one `{nodes, edges}` per rung; FBD: one sheet).

Every LD/FBD body becomes the same graph `Element`s the PLCopen reader builds, and goes through the
same translation (netst, docs/ladder.md): an LD parallel branch is a wired OR, a ladder block's pin
variables are in/out variable elements, exactly as Editor v4 itself writes them to PLCopen XML.  Each
generated ST line keeps its origin (file, line, POU, rung and node), so a diagnostic of the translation
or of the compiler names the editor's file, POU and node.
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

from .. import ast as A
from ..diagnostics import Diagnostics, InternalError, Pos
from ..driver import display_name
from ..parser import parse
from ..stdfuncs import STD_FUNCS
from .graph import Element, GraphError, Pin, Ref
from .netst import CONVERSION, Context, Sig, Translator
from .project import comment, standard_fb_sigs, standard_function_sigs

FOLDERS = {"programs": "PROGRAM", "functions": "FUNCTION", "function-blocks": "FUNCTION_BLOCK"}
LANGUAGES = {".st": "ST", ".ld": "LD", ".fbd": "FBD"}
UNSUPPORTED = {".il": "IL", ".py": "Python", ".cpp": "C/C++", ".json": "the pre-text JSON POU format"}
HEADER = re.compile(r"\s*(PROGRAM|FUNCTION_BLOCK|FUNCTION)\s+(\w+)(?:\s*:\s*(\w+))?", re.I)
VAR_START = re.compile(r"\b(VAR_INPUT|VAR_OUTPUT|VAR_IN_OUT|VAR_EXTERNAL|VAR_TEMP|VAR_GLOBAL|VAR)\b", re.I)
END_VAR = re.compile(r"\bEND_VAR\b", re.I)
DOC = re.compile(r"^\s*\(\*.*?\*\)\s*\n", re.S)
JSON_ID = re.compile(r'"id"\s*:\s*"((?:[^"\\]|\\.)*)"')
CONTACT_EDGE = {"risingEdge": "rising", "fallingEdge": "falling"}
RUNG_SPACING = 1_000_000.0          # keeps the rungs of an LD body in their drawn order


class EditorError(Exception):
    """A problem with the project, positioned in one of its files."""

    def __init__(self, message: str, file: str, line: int = 0, col: int = 0, pou: str = "", where: str = ""):
        super().__init__(message)
        self.file = file
        self.line = line
        self.col = col
        self.pou = pou
        self.where = where

    def report(self, diags: Diagnostics) -> None:
        diags.error(Pos(self.file, self.line, self.col or (1 if self.line else 0)),
                    prefix(self.pou, self.where) + str(self))


def prefix(pou: str, where: str) -> str:
    if not pou:
        return ""
    return f"in {pou}, {where}: " if where else f"in {pou}: "


@dataclass(frozen=True)
class Origin:
    """Where an output line comes from: file and line, exact (copied text) or generated for a node."""
    file: str
    line: int
    pou: str = ""
    where: str = ""
    exact: bool = False


@dataclass
class Unit:
    name: str
    kind: str
    source: str                                   # file it comes from, as displayed
    language: str = "ST"
    networks: int = 0
    lines: list[tuple[str, Origin]] = field(default_factory=list)

    def add(self, text: str, origin: Origin) -> None:
        for part in text.split("\n"):
            self.lines.append((part, origin))


# ------------------------------------------------------------------ JSON shapes --
def objs(v, what: str, file: str, line: int = 1, pou: str = "") -> list[dict]:
    """A JSON list of objects (absent: empty), or EditorError naming what is malformed."""
    if v is None:
        return []
    if not isinstance(v, list) or not all(isinstance(x, dict) for x in v):
        raise EditorError(f"{what} is not a list of objects", file, line, 0, pou)
    return v


def obj(v) -> dict:
    return v if isinstance(v, dict) else {}


# ------------------------------------------------------------------ text helpers --
def line_col(text: str, offset: int) -> tuple[int, int]:
    line = text.count("\n", 0, offset) + 1
    return line, offset - (text.rfind("\n", 0, offset) + 1) + 1


def load_json(text: str, file: str):
    """A whole JSON file, or EditorError at the fault's position."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise EditorError(f"malformed JSON: {e.msg}", file, e.lineno, e.colno) from None


@dataclass
class PouText:
    """One POU file cut into its parts as Editor v4 writes them."""
    path: Path
    file: str
    text: str
    kind: str
    name: str
    ret: str
    decl_end: int          # offset just after the last END_VAR (or the header)
    body_start: int
    body_end: int          # offset of the END_ keyword

    @property
    def body(self) -> str:
        return self.text[self.body_start:self.body_end]


def split_pou(path: Path, file: str, text: str, kind: str) -> PouText:
    """Doc comment, header, VAR blocks, body and END_ keyword of a POU file (EditorError when one is missing)."""
    doc = DOC.match(text)
    start = doc.end() if doc else 0
    head = HEADER.match(text, start)
    if head is None:
        line = line_col(text, start)[0]
        raise EditorError(f"no {kind} header (the file is in the folder for {kind} POUs)", file, line, 0, path.stem)
    if head.group(1).upper() != kind:
        line, col = line_col(text, head.start(1))
        raise EditorError(f"the header says {head.group(1).upper()}, but the file is in the folder for {kind} POUs",
                          file, line, col, head.group(2))
    name, ret = head.group(2), head.group(3) or ""
    if kind == "FUNCTION" and not ret:
        raise EditorError(f"FUNCTION {name} has no return type", file, line_col(text, head.end())[0], 0, name)
    decl_end = head.end()
    if VAR_START.search(text, head.end()):
        ends = list(END_VAR.finditer(text, head.end()))
        if ends:
            decl_end = ends[-1].end()
    end_kw = f"END_{kind}"
    end = [m for m in re.finditer(rf"\b{end_kw}\b", text, re.I) if m.start() >= decl_end]
    if not end:
        raise EditorError(f"no {end_kw} at the end", file, text.count("\n") + 1, 0, name)
    return PouText(path, file, text, kind, name, ret, decl_end, decl_end, end[-1].start())


# ------------------------------------------------------------------ the project --
class EditorProject:
    """The folder read into ST units; errors collect in `errors` (EditorError), one run reports them all."""

    def __init__(self, root: Path):
        self.root = root
        self.units: list[Unit] = []
        self.errors: list[EditorError] = []
        self.warnings: list[EditorError] = []
        self.sigs: dict[str, Sig] = {**standard_function_sigs(), **standard_fb_sigs()}
        self.known_blocks = set(self.sigs) | set(STD_FUNCS)
        self.global_types: dict[str, str] = {}
        self.type_names: set[str] = set()

    def file(self, rel: str) -> str:
        return display_name(self.root / rel)

    # -------------------------------------------------------------------- read --
    def read(self) -> list[Unit]:
        pj = self.root / "project.json"
        pj_name = self.file("project.json")
        try:
            pj_text = pj.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as e:
            self.errors.append(EditorError(f"cannot read: {getattr(e, 'strerror', None) or e}", pj_name))
            return []
        try:
            project = load_json(pj_text, pj_name)
            data = self.project_data(project, pj_name)
        except EditorError as e:
            self.errors.append(e)
            return []
        pous = self.pou_files()
        try:
            data_types = objs(data.get("dataTypes"), "data.dataTypes", pj_name)
            config = obj(obj(data.get("configuration")).get("resource"))
            for key in ("tasks", "instances", "globalVariables"):
                objs(config.get(key), f"data.configuration.resource.{key}", pj_name,
                     find_key_line(pj_text, key))
        except EditorError as e:
            self.errors.append(e)
            return []
        for dt in data_types:
            self.type_names.add(str(dt.get("name", "")).upper())
        for v in config.get("globalVariables") or []:
            name = str(v.get("name", ""))
            try:
                self.global_types[name.upper()] = self.var_type(v.get("type"), pj_name, pj_text, name)
            except EditorError:
                pass          # reported with the configuration
        for p in list(pous):
            try:
                self.signature(p)
            except EditorError as e:
                self.errors.append(e)
                pous.remove(p)
        for dt in data_types:
            self.guard(self.data_type, dt, pj_name, pj_text)
        for p in pous:
            self.guard(self.pou, p)
        self.guard(self.configuration, config, pj_name, pj_text)
        return self.units

    def guard(self, reader, *args) -> None:
        try:
            unit = reader(*args)
        except EditorError as e:
            self.errors.append(e)
            return
        if unit is not None:
            self.units.append(unit)

    def project_data(self, project, pj_name: str) -> dict:
        if not isinstance(project, dict) or not isinstance(project.get("data"), dict):
            raise EditorError("not an Editor v4 project.json (no \"data\" object)", pj_name, 1)
        data = project["data"]
        if data.get("pous"):
            raise EditorError("project.json still holds its POUs in data.pous (an older Editor layout); open and "
                              "save the project once in Editor v4 so each POU gets its own file", pj_name, 1)
        if not isinstance(data.get("dataTypes", []), list):
            raise EditorError("data.dataTypes is not a list", pj_name, 1)
        conf = data.get("configuration")
        if conf is not None and not isinstance(obj(conf).get("resource"), dict):
            raise EditorError("data.configuration has no \"resource\" object", pj_name, 1)
        return data

    def pou_files(self) -> list[PouText]:
        found: list[PouText] = []
        for folder, kind in FOLDERS.items():
            d = self.root / "pous" / folder
            if not d.is_dir():
                continue
            for path in sorted(d.iterdir()):
                ext = path.suffix.lower()
                rel = f"pous/{folder}/{path.name}"
                if ext in UNSUPPORTED:
                    self.errors.append(EditorError(f"{UNSUPPORTED[ext]} POUs are not supported (write it in ST, "
                                                   "LD or FBD)", self.file(rel), 1, 0, path.stem))
                    continue
                if ext not in LANGUAGES or not path.is_file():
                    continue
                try:
                    text = path.read_text(encoding="utf-8")
                    found.append(split_pou(path, self.file(rel), text, kind))
                except UnicodeDecodeError:
                    self.errors.append(EditorError("not UTF-8 text", self.file(rel), 1, 0, path.stem))
                except OSError as e:
                    self.errors.append(EditorError(f"cannot read: {e.strerror or e}", self.file(rel), 0, 0,
                                                   path.stem))
                except EditorError as e:
                    self.errors.append(e)
        names: dict[str, str] = {}
        for p in found:
            if p.name.upper() in names:
                self.errors.append(EditorError(f"POU {p.name} is also defined in {names[p.name.upper()]}", p.file,
                                               1, 0, p.name))
            names.setdefault(p.name.upper(), p.file)
        return found

    # -------------------------------------------------------------- signatures --
    def declarations(self, p: PouText) -> A.Pou:
        """The POU's header and VAR blocks, parsed by our parser at their place in the file."""
        d = Diagnostics()
        tree = parse(p.text[:p.decl_end] + f"\nEND_{p.kind}\n", p.file, d)
        if d.has_errors():
            first = d.sorted()[0]
            raise EditorError(first.message, p.file, first.pos.line, first.pos.col, p.name)
        pous = [i for i in tree.items if isinstance(i, A.Pou)]
        if not pous:
            raise EditorError("no POU declaration", p.file, 1, 0, p.name)
        return pous[0]

    def signature(self, p: PouText) -> None:
        pou = self.declarations(p)
        s = Sig(p.kind, ret=p.ret.upper() or None)
        for d in pou.decls():
            t = spec_text(d, p.text)
            if d.section in ("VAR_INPUT", "VAR_IN_OUT"):
                s.inputs[d.name.upper()] = t
            if d.section in ("VAR_OUTPUT", "VAR_IN_OUT"):
                s.outputs[d.name.upper()] = t
        self.sigs[p.name.upper()] = s
        self.known_blocks.add(p.name.upper())
        self.type_names.add(p.name.upper())

    # ------------------------------------------------------------------- types --
    def var_type(self, t, file: str, text: str, name: str) -> str:
        if not isinstance(t, dict):
            raise EditorError(f"variable {name} has no type", file, find_line(text, name))
        d, v = t.get("definition"), t.get("value")
        if d == "base-type" and isinstance(v, str) and v:
            return v.upper()
        if d in ("user-data-type", "derived") and isinstance(v, str) and v:
            return v
        if d == "array":
            data = obj(t.get("data"))
            base = self.var_type(data.get("baseType"), file, text, name)
            dim_list = objs(data.get("dimensions"), f"array {name}: dimensions", file, find_line(text, name))
            dims = ", ".join(str(x.get("dimension", "")) for x in dim_list)
            if not dims:
                raise EditorError(f"array variable {name} has no dimensions", file, find_line(text, name))
            return f"ARRAY [{dims}] OF {base}"
        raise EditorError(f"variable {name}: type {json.dumps(t)} is not one Editor v4 writes", file,
                          find_line(text, name))

    def data_type(self, dt, file: str, text: str) -> Unit:
        if not isinstance(dt, dict) or not dt.get("name"):
            raise EditorError("a data type without a name", file, 1)
        name = str(dt["name"])
        line = find_line(text, name)
        here = Origin(file, line, name)
        unit = Unit(name, "TYPE", file)
        init = dt.get("initialValue")
        tail = f" := {init}" if init not in (None, "") else ""
        deriv = dt.get("derivation")
        unit.add("TYPE", here)
        if deriv == "structure":
            unit.add(f"    {name} : STRUCT", here)
            for m in objs(dt.get("variable"), f"structure {name}: variable", file, line, name):
                mname = str(m.get("name", ""))
                mtype = self.var_type(m.get("type"), file, text, f"{name}.{mname}")
                minit = obj(obj(m.get("initialValue")).get("simpleValue")).get("value")
                unit.add(f"        {mname} : {mtype}" + (f" := {minit}" if minit not in (None, "") else "") + ";",
                         Origin(file, find_line(text, mname, line), name))
            unit.add("    END_STRUCT;", here)
        elif deriv == "enumerated":
            values = [str(v.get("description", "")) for v in objs(dt.get("values"), f"enumeration {name}: values",
                                                                   file, line, name)]
            if not values:
                raise EditorError(f"enumeration {name} has no values", file, line, 0, name)
            unit.add(f"    {name} : ({', '.join(values)}){tail};", here)
        elif deriv == "array":
            base = self.var_type(dt.get("baseType"), file, text, name)
            dims = ", ".join(str(x.get("dimension", "")) for x in objs(dt.get("dimensions"),
                                                                        f"array {name}: dimensions", file, line, name))
            unit.add(f"    {name} : ARRAY [{dims}] OF {base}{tail};", here)
        else:
            raise EditorError(f"data type {name}: derivation {deriv!r} (structure, enumerated or array)", file, line,
                              0, name)
        unit.add("END_TYPE", here)
        return unit

    # ------------------------------------------------------------------- POUs --
    def pou(self, p: PouText) -> Unit:
        language = LANGUAGES[p.path.suffix.lower()]
        unit = Unit(p.name, p.kind, p.file, language)
        if language == "ST":
            for k, part in enumerate(p.text.rstrip("\n").split("\n")):
                unit.lines.append((part, Origin(p.file, k + 1, p.name, exact=True)))
            return unit
        head = p.text[:p.decl_end]
        for k, part in enumerate(head.split("\n")):
            unit.lines.append((part, Origin(p.file, k + 1, p.name, exact=True)))
        pou = self.declarations(p)
        var_types = dict(self.global_types)
        taken = set(self.type_names) | set(self.sigs)
        for d in pou.decls():
            var_types[d.name.upper()] = spec_text(d, p.text)
            taken.add(d.name.upper())
        if p.kind == "FUNCTION":
            var_types[p.name.upper()] = p.ret
        raw = p.body
        lead = len(raw) - len(raw.lstrip())
        start_line = line_col(p.text, p.body_start + lead)[0]
        try:
            value = json.loads(raw)
        except json.JSONDecodeError as e:
            line, col = line_col(p.text, p.body_start + e.pos)
            raise EditorError(f"malformed JSON body: {e.msg}", p.file, line, col, p.name) from None
        graph = Graph(p, start_line, raw.lstrip(), self.known_blocks)
        elems = graph.ld(value) if language == "LD" else graph.fbd(value)
        graph.check_connectors(elems)
        ctx = Context(p.name, p.kind, var_types, self.sigs, taken)
        try:
            result = Translator(elems, ctx, language).run()
        except GraphError as e:
            raise EditorError(str(e), p.file, e.line, 0, p.name, graph.where(e.local_id)) from None
        except RecursionError:
            raise EditorError("the wiring of this body is nested or looped too deeply to translate", p.file,
                              start_line, 0, p.name) from None
        except (TypeError, KeyError, AttributeError, ValueError, IndexError) as e:
            # a graph the translation does not handle: a bug of plc, reported as one (exit 3), never a traceback
            raise InternalError(Pos(p.file, start_line, 1), f"in {p.name}: the {language} translation failed: "
                                f"{type(e).__name__}: {e}") from None
        unit.networks = result.networks
        for msg, el in result.warnings:
            self.warnings.append(EditorError(msg, p.file, el.line, 0, p.name, graph.where(el.id)))
        gen = Origin(p.file, start_line, p.name)
        if result.decls:
            unit.add(f"VAR (* generated from the {language} body: power flow shared by several elements, edge "
                     "detectors and block outputs, named after their node's localId *)", gen)
            width = max(len(d[0]) for d in result.decls)
            for dname, dtype, dcomment, lid in result.decls:
                o = graph.origin(lid) if lid is not None else gen
                unit.add(f"    {dname.ljust(width)} : {dtype}; (* {comment(dcomment)} *)", o)
            unit.add("END_VAR", gen)
        for ln in result.lines:
            unit.add(ln.text, graph.origin(ln.local_id) if ln.local_id is not None else gen)
        end_line = line_col(p.text, p.body_end)[0]
        unit.add(f"END_{p.kind}", Origin(p.file, end_line, p.name, exact=True))
        return unit

    # ---------------------------------------------------------- configuration --
    def configuration(self, res: dict, file: str, text: str) -> Unit | None:
        tasks = objs(res.get("tasks"), "tasks", file)
        instances = objs(res.get("instances"), "instances", file)
        globals_ = objs(res.get("globalVariables"), "globalVariables", file)
        if not (tasks or instances or globals_):
            return None
        base = text.find('"configuration"')
        cline = line_col(text, base)[0] if base >= 0 else 1
        here = Origin(file, cline, "Config0")
        unit = Unit("Config0", "CONFIGURATION", file)
        unit.add("CONFIGURATION Config0", here)
        unit.add("    RESOURCE Res0 ON PLC", here)
        plain = [v for v in globals_ if isinstance(v, dict) and not v.get("location")]
        located = [v for v in globals_ if isinstance(v, dict) and v.get("location")]
        for group in (plain, located):   # MATIEC rejects a block mixing located and unlocated variables
            if not group:
                continue
            unit.add("        VAR_GLOBAL", here)
            for v in group:
                name = str(v.get("name", ""))
                line = find_line(text, name, cline)
                vt = self.var_type(v.get("type"), file, text, name)
                at = f" AT {v['location']}" if v.get("location") else ""
                init = v.get("initialValue")
                doc = str(v.get("documentation") or "").strip()
                unit.add(f"            {name}{at} : {vt}" + (f" := {init}" if init not in (None, "") else "") + ";"
                         + (f" (* {comment(doc)} *)" if doc else ""), Origin(file, line, "Config0"))
            unit.add("        END_VAR", here)
        for t in tasks:
            name = str(t.get("name", ""))
            line = find_line(text, name, cline)
            if t.get("triggering") != "Cyclic":
                raise EditorError(f"task {name}: only Cyclic tasks can be imported (an Interrupt task names no "
                                  "SINGLE variable in Editor v4's project)", file, line, 0, "Config0")
            try:
                priority = int(t.get("priority") or 0)
            except (TypeError, ValueError):
                raise EditorError(f"task {name}: priority {t.get('priority')!r} is not a number", file, line, 0,
                                  "Config0") from None
            unit.add(f"        TASK {name}(INTERVAL := {t.get('interval')}, PRIORITY := {priority});",
                     Origin(file, line, "Config0"))
        for i in instances:
            name = str(i.get("name", ""))
            line = find_line(text, name, cline)
            task = f" WITH {i['task']}" if i.get("task") else ""
            unit.add(f"        PROGRAM {name}{task} : {i.get('program')};", Origin(file, line, "Config0"))
        unit.add("    END_RESOURCE", here)
        unit.add("END_CONFIGURATION", here)
        return unit


def spec_text(d: A.VarDecl, text: str) -> str:
    """The type of a declaration as ST text ('' when it is not a named type)."""
    if isinstance(d.spec, A.TypeRef):
        return d.spec.name
    return ""


def find_key_line(text: str, key: str) -> int:
    m = re.search(r'"' + re.escape(key) + r'"\s*:', text)
    return line_col(text, m.start())[0] if m else 1


def find_line(text: str, name: str, after_line: int = 1) -> int:
    """Line of the first `"name": "<name>"` at or after a line of a JSON text (1 when not found)."""
    start = 0
    for _ in range(after_line - 1):
        nxt = text.find("\n", start)
        if nxt < 0:
            break
        start = nxt + 1
    m = re.compile(r'"(?:name|description)"\s*:\s*"' + re.escape(name) + '"').search(text, start)
    return line_col(text, m.start())[0] if m else after_line


# ------------------------------------------------------------------ the bodies --
class Graph:
    """The nodes and edges of one LD or FBD body as graph Elements (localId: the node's numericId when it
    is a unique number, else a counter), with the file line of every node for diagnostics."""

    def __init__(self, p: PouText, start_line: int, body: str, known_blocks: set[str]):
        self.p = p
        self.known = known_blocks
        self.lines: dict[str, int] = {}
        for m in JSON_ID.finditer(body):
            self.lines.setdefault(m.group(1), start_line + body.count("\n", 0, m.start()))
        self.start_line = start_line
        self.labels: dict[int, str] = {}
        self.json_ids: dict[int, str] = {}
        self.node_lines: dict[int, int] = {}
        self.used: set[int] = set()
        self.next_id = 1

    # ---------------------------------------------------------------- helpers --
    def error(self, message: str, node_id: str = "", where: str = "") -> EditorError:
        line = self.lines.get(node_id, self.start_line)
        return EditorError(message, self.p.file, line, 0, self.p.name, where)

    def where(self, local_id: int | None) -> str:
        return self.labels.get(local_id, "") if local_id is not None else ""

    def origin(self, local_id: int | None) -> Origin:
        return Origin(self.p.file, self.node_lines.get(local_id, self.start_line), self.p.name, self.where(local_id))

    def local_id(self, node: dict) -> int:
        raw = str(obj(node.get("data")).get("numericId", ""))
        lid = int(raw) if raw.isdigit() and int(raw) < 2**31 else 0
        if lid == 0 or lid in self.used:
            while self.next_id in self.used:
                self.next_id += 1
            lid = self.next_id
        self.used.add(lid)
        return lid

    def nodes_edges(self, holder, where: str) -> tuple[list[dict], list[dict]]:
        if not isinstance(holder, dict):
            raise self.error(f"{where} is not an object with nodes and edges")
        nodes, edges = holder.get("nodes"), holder.get("edges")
        if not isinstance(nodes, list) or not isinstance(edges, list):
            raise self.error(f"{where} has no \"nodes\" and \"edges\" lists")
        for n in nodes:
            if not isinstance(n, dict) or not isinstance(n.get("id"), str) or not isinstance(n.get("type"), str) \
                    or not isinstance(n.get("data"), dict):
                nid = n.get("id", "") if isinstance(n, dict) else ""
                raise self.error("a node needs a string \"id\", a \"type\" and a \"data\" object", str(nid), where)
        for e in edges:
            if not isinstance(e, dict) or not all(isinstance(e.get(k), str) for k in ("id", "source", "target")):
                eid = e.get("id", "") if isinstance(e, dict) else ""
                raise self.error("an edge needs string \"id\", \"source\" and \"target\"", str(eid), where)
        return nodes, edges

    def element(self, node: dict, kind: str, where: str, y_shift: float) -> Element:
        lid = self.local_id(node)
        pos = obj(node.get("position"))
        try:
            x, y = float(pos.get("x", 0)), float(pos.get("y", 0))
        except (TypeError, ValueError):
            x, y = 0.0, 0.0
        order = obj(node.get("data")).get("executionOrder") or 0
        e = Element(lid, kind, self.lines.get(node["id"], self.start_line), x, y + y_shift,
                    int(order) if isinstance(order, (int, float)) else 0)
        self.json_ids[lid] = node["id"]
        self.labels[lid] = f"{where}, node '{node['id']}' (localId {lid})" if where else \
            f"node '{node['id']}' (localId {lid})"
        self.node_lines[lid] = e.line
        return e

    @staticmethod
    def name(node: dict) -> str:
        v = node["data"].get("variable")
        return str(v.get("name", "")).strip() if isinstance(v, dict) else ""

    def block(self, node: dict, where: str, y_shift: float) -> Element:
        data = node["data"]
        variant = data.get("variant") if isinstance(data.get("variant"), dict) else {}
        e = self.element(node, "block", where, y_shift)
        e.type_name = str(variant.get("name", "")).strip()
        if not e.type_name:
            raise self.error("a block without a type name", node["id"], where)
        if e.type_name.upper() not in self.known and not CONVERSION.match(e.type_name):
            raise self.error(f"unknown block type '{e.type_name}': neither a standard function or function "
                             "block nor a POU of this project", node["id"], self.labels[e.id])
        if variant.get("type") == "function-block" or e.type_name.upper() in standard_fb_sigs():
            e.instance = self.name(node)
        where_ = self.labels[e.id]
        ins = [str(h.get("id")) for h in objs(data.get("inputHandles"), "inputHandles", self.p.file, e.line,
                                               self.p.name)]
        outs = [str(h.get("id")) for h in objs(data.get("outputHandles"), "outputHandles", self.p.file, e.line,
                                                self.p.name)]
        if not ins and not outs:
            for v in objs(variant.get("variables"), f"{where_}: variant.variables", self.p.file, e.line, self.p.name):
                cls = v.get("class")
                if cls in ("input", "inOut"):
                    ins.append(str(v.get("name")))
                if cls in ("output", "inOut"):
                    outs.append(str(v.get("name")))
        for pin in ins:
            e.pin_text[pin.upper()] = pin
            e.inputs[pin.upper()] = Pin(pin.upper())
        for pin in outs:
            e.pin_text[pin.upper()] = pin
            e.outputs[pin.upper()] = Pin(pin.upper())
            if pin.upper() in e.inputs:
                e.inouts.append(pin.upper())
        return e

    def wire(self, edges: list[dict], by_node: dict[str, dict], elems: dict[str, Element], where: str) -> None:
        """Every edge as a Ref on its target's input pin; parallel nodes (LD) pass their inputs through."""
        into: dict[str, list[dict]] = {}
        for ed in edges:
            for end in ("source", "target"):
                if ed[end] not in by_node:
                    raise self.error(f"edge '{ed['id']}' {'comes from' if end == 'source' else 'goes to'} node "
                                     f"'{ed[end]}', which {where or 'the FBD sheet'} does not have",
                                     ed["id"], where)
            into.setdefault(ed["target"], []).append(ed)

        def sources(ed: dict, seen: frozenset) -> list[tuple[Element, str]]:
            src = by_node[ed["source"]]
            if src["type"] == "parallel":
                if src["id"] in seen:
                    raise self.error("parallel branches wired in a loop", src["id"], where)
                return [s for up in into.get(src["id"], []) for s in sources(up, seen | {src["id"]})]
            el = elems.get(src["id"])
            if el is None:
                return []            # an LD pin variable: wired through the block's data, not its edge
            pin = str(ed.get("sourceHandle") or "").upper() if el.kind == "block" else ""
            return [(el, pin)]

        for ed in edges:
            target = elems.get(ed["target"])
            if target is None or "variable" in (by_node[ed["source"]]["type"], by_node[ed["target"]]["type"]):
                continue         # an LD pin variable is wired through its block's data (ld_pin_variables)
            if target.kind == "block":
                pin = str(ed.get("targetHandle") or "").upper()
                if pin not in target.inputs:
                    raise self.error(f"edge '{ed['id']}' goes to pin '{ed.get('targetHandle')}' of block "
                                     f"{target.type_name}, which has no such input", ed["id"], self.labels[target.id])
            else:
                pin = ""
                if pin not in target.inputs:
                    raise self.error(f"edge '{ed['id']}' goes into {target.kind} node '{ed['target']}', which has no "
                                     "input", ed["id"], self.labels[target.id])
            for el, spin in sources(ed, frozenset()):
                target.inputs[pin].refs.append(Ref(el.id, spin, self.lines.get(ed["id"], target.line)))

    def check_connectors(self, elems: list[Element]) -> None:
        """Every connector has a wire into it and every continuation a connector of its name, read or not (the
        shared checks, graph.check_connectors and check_loops, run in Translator.run: the latter finds wire loops
        through no block, continuation -> connector included, and reports them at this body's node too)."""
        connectors = {e.text.upper(): e for e in elems if e.kind == "connector"}
        for e in elems:
            if e.kind == "connector" and not e.inputs[""].refs:
                raise self.error(f"connector '{e.text}' has nothing wired into it", self.json_ids.get(e.id, ""),
                                 self.labels.get(e.id, ""))
            if e.kind == "continuation" and e.text.upper() not in connectors:
                raise self.error(f"continuation '{e.text}' has no connector of that name", self.json_ids.get(e.id, ""),
                                 self.labels.get(e.id, ""))

    # --------------------------------------------------------------------- LD --
    def ld(self, value) -> list[Element]:
        if not isinstance(value, dict) or not isinstance(value.get("rungs"), list):
            raise self.error("an LD body is an object with a \"rungs\" list")
        out: list[Element] = []
        for r, rung in enumerate(value["rungs"], 1):
            where = f"rung {r}"
            nodes, edges = self.nodes_edges(rung, f"rung {r}")
            by_node = {n["id"]: n for n in nodes}
            elems: dict[str, Element] = {}
            shift = r * RUNG_SPACING
            text = str(rung.get("comment") or "").strip()
            if text:
                c = Element(self.local_id({}), "comment", self.lines.get(str(rung.get("id")), self.start_line),
                            0.0, shift - 1.0, 0, text=text)
                out.append(c)
            for n in nodes:
                t, data = n["type"], n["data"]
                if t == "powerRail":
                    e = self.element(n, "leftPowerRail" if data.get("variant") == "left" else "rightPowerRail",
                                     where, shift)
                    if e.kind == "leftPowerRail":
                        e.outputs[""] = Pin("")
                    else:
                        e.inputs[""] = Pin("")
                elif t in ("contact", "coil"):
                    e = self.element(n, t, where, shift)
                    e.text = self.name(n)
                    if not e.text:
                        raise self.error(f"{t} without a variable", n["id"], self.labels[e.id])
                    variant = data.get("variant") or "default"
                    allowed = ("default", "negated", "risingEdge", "fallingEdge") + (("set", "reset") if t == "coil"
                                                                                      else ())
                    if variant not in allowed:
                        raise self.error(f"{t} variant '{variant}' ({', '.join(allowed)})", n["id"], self.labels[e.id])
                    e.negated = variant == "negated"
                    e.edge = CONTACT_EDGE.get(variant, "none")
                    e.storage = variant if variant in ("set", "reset") else "none"
                    e.inputs[""] = Pin("")
                    e.outputs[""] = Pin("")
                elif t == "block":
                    e = self.block(n, where, shift)
                elif t == "variable":
                    e = self.ld_variable(n, by_node, where, shift)
                    if e is None:
                        continue
                elif t == "parallel":
                    if data.get("type") not in ("open", "close"):
                        raise self.error("a parallel node is 'open' or 'close'", n["id"], where)
                    continue
                else:
                    raise self.error(f"unknown LD node type '{t}'", n["id"], where)
                elems[n["id"]] = e
            self.wire(edges, by_node, elems, where)
            self.ld_pin_variables(nodes, by_node, elems, where)
            out.extend(elems.values())
        return out

    def ld_variable(self, n: dict, by_node: dict, where: str, shift: float) -> Element | None:
        """A ladder block's pin variable: an in-variable feeding an input, an out-variable fed by an output."""
        data = n["data"]
        name = self.name(n)
        if not name:
            return None              # Editor v4 leaves an unnamed pin variable out of its XML too
        block = data.get("block") if isinstance(data.get("block"), dict) else {}
        if not isinstance(block.get("id"), str) or block["id"] not in by_node:
            raise self.error(f"variable '{name}' belongs to block node '{block.get('id')}', which this rung does "
                             "not have", n["id"], where)
        variant = data.get("variant")
        if variant == "input":
            e = self.element(n, "inVariable", where, shift)
            e.outputs[""] = Pin("")
        elif variant == "output":
            e = self.element(n, "outVariable", where, shift)
            e.inputs[""] = Pin("")
        else:
            raise self.error(f"variable variant '{variant}' (input or output)", n["id"], where)
        e.text = name
        return e

    def ld_pin_variables(self, nodes: list[dict], by_node: dict, elems: dict[str, Element], where: str) -> None:
        for n in nodes:
            if n["type"] != "variable" or n["id"] not in elems:
                continue
            e = elems[n["id"]]
            block = elems[n["data"]["block"]["id"]]
            pin = str(n["data"]["block"].get("handleId") or "").upper()
            line = self.lines.get(n["id"], e.line)
            if e.kind == "inVariable":
                if pin not in block.inputs:
                    raise self.error(f"variable '{e.text}' feeds pin '{pin}' of block {block.type_name}, which has no "
                                     "such input", n["id"], self.labels[e.id])
                block.inputs[pin].refs.append(Ref(e.id, "", line))
            else:
                if pin not in block.outputs:
                    raise self.error(f"variable '{e.text}' reads pin '{pin}' of block {block.type_name}, which has no "
                                     "such output", n["id"], self.labels[e.id])
                e.inputs[""].refs.append(Ref(block.id, pin, line))

    # -------------------------------------------------------------------- FBD --
    def fbd(self, value) -> list[Element]:
        if not isinstance(value, dict) or not isinstance(value.get("rung"), dict):
            raise self.error("an FBD body is an object with a \"rung\" holding its nodes and edges")
        nodes, edges = self.nodes_edges(value["rung"], "the FBD sheet")
        by_node = {n["id"]: n for n in nodes}
        elems: dict[str, Element] = {}
        for n in nodes:
            t, data = n["type"], n["data"]
            if t == "block":
                e = self.block(n, "", 0.0)
            elif t in ("input-variable", "output-variable", "inout-variable"):
                kind = {"input-variable": "inVariable", "output-variable": "outVariable",
                        "inout-variable": "inOutVariable"}[t]
                e = self.element(n, kind, "", 0.0)
                e.text = self.name(n)
                if not e.text:
                    raise self.error(f"{t} without a variable or expression", n["id"], self.labels[e.id])
                e.negated = bool(data.get("negated"))
                if kind != "outVariable":
                    e.outputs[""] = Pin("")
                if kind != "inVariable":
                    e.inputs[""] = Pin("")
            elif t in ("connector", "continuation"):
                e = self.element(n, t, "", 0.0)
                e.text = self.name(n)
                if not e.text:
                    raise self.error(f"{t} without a name", n["id"], self.labels[e.id])
                if t == "connector":
                    e.inputs[""] = Pin("")
                else:
                    e.outputs[""] = Pin("")
            elif t == "comment":
                e = self.element(n, "comment", "", 0.0)
                e.text = str(data.get("content") or "").strip()
            else:
                raise self.error(f"unknown FBD node type '{t}'", n["id"])
            elems[n["id"]] = e
        self.wire(edges, by_node, elems, "")
        return list(elems.values())


# ----------------------------------------------------------------- entry point --
def looks_like_project(path: Path) -> bool:
    return path.is_dir() and (path / "project.json").is_file()


def read_folder(root: Path, diags: Diagnostics) -> list[Unit] | None:
    """The units of the project folder; None (errors in diags) when any part could not be read."""
    proj = EditorProject(root)
    units = proj.read()
    for w in proj.warnings:
        diags.warning(Pos(w.file, w.line, w.col or 1), prefix(w.pou, w.where) + str(w))
    for e in proj.errors:
        e.report(diags)
    return None if proj.errors else units


def unit_texts(units: list[Unit], command: str) -> dict[str, tuple[str, list[Origin]]]:
    """File name -> (ST text, origin of each line) for every unit."""
    out: dict[str, tuple[str, list[Origin]]] = {}
    for u in units:
        what = f"; {u.language} body, {u.networks} {'rung' if u.language == 'LD' else 'network'}(s)" \
            if u.language in ("LD", "FBD") else ""
        head = (f"(* imported from {u.source} by `{command}`{what} *)",
                Origin(u.source, u.lines[0][1].line if u.lines else 1, u.name))
        name = f"{u.name}.st"
        n = 2
        while name in out:
            name = f"{u.name}_{n}.st"
            n += 1
        lines = [head, *u.lines]
        out[name] = ("\n".join(t for t, _o in lines) + "\n", [o for _t, o in lines])
    return out


def remap(diags: Diagnostics, tables: dict[str, list[Origin]]) -> None:
    """Diagnostics on the generated ST moved to the editor's file, line and node."""
    for d in diags.items:
        table = tables.get(d.pos.file)
        if table is None or not 1 <= d.pos.line <= len(table):
            continue
        o = table[d.pos.line - 1]
        d.pos = Pos(o.file, o.line, d.pos.col if o.exact else 1)
        d.message = prefix(o.pou, o.where) + d.message
