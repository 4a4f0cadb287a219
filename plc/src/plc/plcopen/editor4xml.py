"""PLCopen XML as OpenPLC Editor v4's import reads it (docs/openplc-editor.md, "Export for Editor v4").

Editor v4 (since mid-2026) imports a PLCopen TC6 file in the neutral dialect its own export writes.  Its
reader is narrower than the schema, and where it does not understand something it mostly drops it
without a word.  `problems(root)` lists what of a document it would lose or refuse; `adapt(root)`
rewrites one of our exports into the shape it reads, and says what that costs:

- a POU interface may hold at most one list of each kind (inputVars, outputVars, inOutVars,
  externalVars, localVars, tempVars): of a kind given twice it reads no variable at all.  Editor v4
  has no CONSTANT or RETAIN lists, so adapt merges the lists of a kind and drops those qualifiers;
- global variables are read from the configuration, not from its resource; program instances only
  from inside a task; one configuration with one resource;
- data types are structures, enumerations or arrays (anything else stops the whole import);
- a variable's type is an elementary type, a string, a derived (named) type or an array of those;
- an LD body keeps power rails, contacts, coils, blocks and in/out variables (comments are dropped,
  in-out variables skipped with a warning; jumps, labels, returns and connectors are not read).
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from lxml import etree

from .datatypes import ELEMENTARY
from .xmlfile import NS, children, line_of, local, parse_bytes

VAR_LISTS = ("inputVars", "outputVars", "inOutVars", "externalVars", "localVars", "tempVars")
DATA_TYPE_KINDS = ("struct", "enum", "array")
LD_READ = {"leftPowerRail", "rightPowerRail", "contact", "coil", "block", "inVariable", "outVariable", "comment"}
STRINGS = ("string", "wstring")


@dataclass
class Problem:
    message: str
    line: int


def leaf_type_ok(holder) -> bool:
    kids = children(holder) if holder is not None else []
    if len(kids) != 1:
        return False
    k = local(kids[0])
    return k == "derived" or k in STRINGS or k.upper() in ELEMENTARY


def type_ok(holder) -> bool:
    kids = children(holder) if holder is not None else []
    if len(kids) == 1 and local(kids[0]) == "array":
        arr = kids[0]
        return leaf_type_ok(child_of(arr, "baseType")) and bool(children(arr, "dimension"))
    return leaf_type_ok(holder)


def child_of(el, name: str):
    found = children(el, name)
    return found[0] if found else None


def variables_problems(holder, where: str) -> list[Problem]:
    out = []
    for v in children(holder, "variable"):
        if not type_ok(child_of(v, "type")):
            t = child_of(v, "type")
            kind = ", ".join(f"<{local(k)}>" for k in children(t)) if t is not None else "none"
            out.append(Problem(f"{where}: variable {v.get('name')} has a type Editor v4 does not read ({kind}; it "
                               "reads elementary types, strings, named types and arrays of those)", line_of(v)))
    return out


def problems(root) -> list[Problem]:
    """What Editor v4's PLCopen import would lose or refuse in the document."""
    out: list[Problem] = []
    types = child_of(root, "types")
    data_types = child_of(types, "dataTypes") if types is not None else None
    for dt in children(data_types, "dataType") if data_types is not None else []:
        base = child_of(dt, "baseType")
        kinds = [local(k) for k in children(base)] if base is not None else []
        if len(kinds) != 1 or kinds[0] not in DATA_TYPE_KINDS:
            out.append(Problem(f"data type {dt.get('name')}: Editor v4 imports structures, enumerations and arrays "
                               f"only (this one is <{'/'.join(kinds) or 'nothing'}>; its import stops here)",
                               line_of(dt)))
        elif kinds[0] == "struct":
            out += variables_problems(child_of(base, "struct"), f"structure {dt.get('name')}")
        elif kinds[0] == "array" and not type_ok(base):
            out.append(Problem(f"data type {dt.get('name')}: an array of a type Editor v4 does not read", line_of(dt)))
    pous = child_of(types, "pous") if types is not None else None
    for p in children(pous, "pou") if pous is not None else []:
        name = p.get("name")
        if p.get("pouType") not in ("program", "function", "functionBlock"):
            out.append(Problem(f"POU {name}: pouType {p.get('pouType')!r} is skipped", line_of(p)))
        iface = child_of(p, "interface")
        for kind in VAR_LISTS:
            lists = children(iface, kind) if iface is not None else []
            if len(lists) > 1:
                out.append(Problem(f"POU {name}: {len(lists)} <{kind}> lists: Editor v4 reads none of their variables "
                                   "(it takes one list of each kind)", line_of(lists[1])))
            for vl in lists:
                out += variables_problems(vl, f"POU {name}")
        for kind in ("globalVars", "accessVars"):
            for vl in children(iface, kind) if iface is not None else []:
                out.append(Problem(f"POU {name}: <{kind}> in a POU interface is not read", line_of(vl)))
        body = child_of(p, "body")
        langs = [local(k) for k in children(body)] if body is not None else []
        if not langs or langs[0] not in ("ST", "IL", "LD", "FBD"):
            out.append(Problem(f"POU {name}: body <{'/'.join(langs) or 'none'}> is skipped", line_of(p)))
            continue
        lang = children(body)[0]
        if langs[0] in ("ST", "IL") and not any(local(k) == "p" for k in children(lang)):
            out.append(Problem(f"POU {name}: the {langs[0]} text is read from an <xhtml:p> only", line_of(lang)))
        if langs[0] == "LD":
            lost = sorted({local(k) for k in children(lang)} - LD_READ)
            if lost:
                out.append(Problem(f"POU {name}: LD elements Editor v4 does not read: {', '.join(lost)}",
                                   line_of(lang)))
            out += ld_rung_problems(name, lang)
    confs = children(child_of(child_of(root, "instances"), "configurations")) \
        if child_of(root, "instances") is not None and child_of(child_of(root, "instances"), "configurations") \
        is not None else []
    if len(confs) > 1:
        out.append(Problem(f"{len(confs)} configurations: Editor v4 reads one", line_of(confs[1])))
    for c in confs[:1]:
        res = children(c, "resource")
        if len(res) != 1:
            out.append(Problem(f"configuration {c.get('name')}: {len(res)} resources, Editor v4 reads exactly one",
                               line_of(c)))
        out += variables_problems(child_of(c, "globalVars"), f"configuration {c.get('name')}") \
            if child_of(c, "globalVars") is not None else []
        if len(children(c, "globalVars")) > 1:
            out.append(Problem("more than one <globalVars> list in the configuration: Editor v4 reads none",
                               line_of(children(c, "globalVars")[1])))
        for r in res:
            for gv in children(r, "globalVars"):
                out.append(Problem(f"resource {r.get('name')}: global variables of a resource are not read (Editor v4 "
                                   "reads those of the configuration)", line_of(gv)))
            for pi in children(r, "pouInstance"):
                out.append(Problem(f"resource {r.get('name')}: program instance {pi.get('name')} outside a task is not "
                                   "read", line_of(pi)))
            for t in children(r, "task"):
                if not t.get("interval"):
                    out.append(Problem(f"task {t.get('name')}: without an interval Editor v4 makes it an Interrupt "
                                       "task with no trigger", line_of(t)))
    return out


def ld_rung_problems(pou: str, ld) -> list[Problem]:
    """Editor v4 makes a rung of every group of elements joined by wires, power rails included, and reads
    the wires of an element's single connectionPointIn: a rail shared by several networks merges them into
    one rung, and a second connectionPointIn (a right rail with one per rung) loses its wires."""
    out = []
    elems = {el.get("localId"): el for el in children(ld) if local(el) in LD_READ - {"comment"}}
    parent = {k: k for k in elems}

    def find(k):
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    ours = {k: k for k in elems}           # our networks: rails join nothing (graph.networks)

    def ours_find(k):
        while ours[k] != k:
            ours[k] = ours[ours[k]]
            k = ours[k]
        return k

    for k, el in elems.items():
        points = list(children(el, "connectionPointIn"))
        for v in children(child_of(el, "inputVariables"), "variable") if child_of(el, "inputVariables") is not None \
                else []:
            points += children(v, "connectionPointIn")
        if local(el) != "block" and len(points) > 1:
            out.append(Problem(f"POU {pou}: {local(el)} {k} has {len(points)} connectionPointIn: Editor v4 reads "
                               "the wires of none of them (draw one rail pair per rung)", line_of(el)))
        for point in points:
            for c in children(point, "connection"):
                src = c.get("refLocalId")
                if src in parent:
                    parent[find(src)] = find(k)
                    if "PowerRail" not in local(el) and "PowerRail" not in local(elems[src]):
                        ours[ours_find(src)] = ours_find(k)
    rails = {k for k, el in elems.items() if "PowerRail" in local(el)}
    editor_rungs = {find(k) for k in elems if k not in rails}
    networks = {ours_find(k) for k in elems if k not in rails}
    if len(editor_rungs) < len(networks):
        out.append(Problem(f"POU {pou}: Editor v4 shows its {len(networks)} networks as {len(editor_rungs)} rung(s): "
                           "they share a power rail (draw one rail pair per rung)", line_of(ld)))
    return out


def editor_view(root) -> dict:
    """The declarations as Editor v4 reads them: POU name -> [(list kind, variable name)], globals, instances."""
    view: dict = {"pous": {}, "globals": [], "instances": [], "types": []}
    types = child_of(root, "types")
    for dt in children(child_of(types, "dataTypes"), "dataType") if types is not None else []:
        view["types"].append(dt.get("name"))
    for p in children(child_of(types, "pous"), "pou") if types is not None else []:
        iface = child_of(p, "interface")
        seen = []
        for kind in VAR_LISTS:
            lists = children(iface, kind) if iface is not None else []
            if len(lists) == 1:
                seen += [(kind, v.get("name")) for v in children(lists[0], "variable")]
        view["pous"][p.get("name")] = seen
    confs = children(child_of(child_of(root, "instances"), "configurations")) \
        if child_of(root, "instances") is not None else []
    if len(confs) == 1:
        c = confs[0]
        gv = children(c, "globalVars")
        if len(gv) == 1:
            view["globals"] = [v.get("name") for v in children(gv[0], "variable")]
        res = children(c, "resource")
        if len(res) == 1:
            view["instances"] = [(pi.get("name"), t.get("name"), pi.get("typeName")) for t in children(res[0], "task")
                                 for pi in children(t, "pouInstance")]
    return view


def adapt(root) -> list[Problem]:
    """Rewrite an export of ours for Editor v4 in place; what it cost (qualifiers dropped) as notes."""
    notes: list[Problem] = []
    types = child_of(root, "types")
    for p in children(child_of(types, "pous"), "pou") if types is not None else []:
        iface = child_of(p, "interface")
        if iface is None:
            continue
        for kind in VAR_LISTS:
            lists = children(iface, kind)
            for vl in lists:
                dropped = [q.upper() for q in ("constant", "retain", "nonretain") if vl.get(q) in ("true", "1")]
                if dropped:
                    notes.append(Problem(f"POU {p.get('name')}: a {' '.join(dropped)} <{kind}> list is written as a "
                                         "plain one (Editor v4 keeps no CONSTANT/RETAIN)", line_of(vl)))
                    for q in ("constant", "retain", "nonretain"):
                        vl.attrib.pop(q, None)
            for extra in lists[1:]:
                for v in children(extra, "variable"):
                    lists[0].append(v)
                iface.remove(extra)
    inst = child_of(root, "instances")
    confs = children(child_of(inst, "configurations")) if inst is not None and \
        child_of(inst, "configurations") is not None else []
    for c in confs:
        gvs = children(c, "globalVars")
        for r in children(c, "resource"):
            gvs += children(r, "globalVars")
        if len(gvs) > 1 or (gvs and gvs[0].getparent() is not c):
            target = etree.Element(f"{{{NS}}}globalVars")
            for gv in gvs:
                if any(gv.get(q) in ("true", "1") for q in ("constant", "retain", "nonretain")):
                    notes.append(Problem("a CONSTANT/RETAIN global variable list is written as a plain one (Editor "
                                         "v4 keeps no CONSTANT/RETAIN)", line_of(gv)))
                for v in children(gv, "variable"):
                    target.append(v)
                gv.getparent().remove(gv)
            # the schema's order in a configuration: resources, then globalVars
            c.append(target)
    return notes


DECL = re.compile(r"^(?:data type|POU|configuration|resource|task|structure) (\w+)")


def declaration_of(p: Problem) -> str:
    """The name of the declaration a problem is about ('' when it names none)."""
    m = DECL.match(p.message)
    return m.group(1) if m else ""


def for_editor(data: bytes) -> tuple[bytes, list[Problem], list[Problem]]:
    """An export of ours made for Editor v4: the new document, what adapting it cost, and what Editor v4 would
    still lose or refuse (lines in the new document)."""
    root = parse_bytes(data)
    notes = adapt(root)
    out = etree.tostring(root, xml_declaration=True, encoding="utf-8", pretty_print=True)
    reparsed = parse_bytes(etree.tostring(etree.fromstring(out, etree.XMLParser(remove_blank_text=True)),
                                          xml_declaration=True, encoding="utf-8", pretty_print=True))
    final = etree.tostring(reparsed, xml_declaration=True, encoding="utf-8", pretty_print=True)
    return final, notes, problems(parse_bytes(final))
