"""What the map needs to know from the ST sources, read with the compiler's own parser.

- enumeration types: MATIEC numbers enum values in declaration order (IEC edition 2 enums have no explicit
  values), so a register that publishes an enum holds that position; the HMI tags list the names in order;
- integer VAR CONSTANTs of every POU (POU.NAME), to prove the reason codes the ST code uses by name agree
  with modbus_map/reason_codes.toml;
- the CASE tables of mapping functions (F_SeqReasonCode, F_RotaryErrorId): enum value -> integer.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from plc.diagnostics import Diagnostics, Pos
from plc.parser import parse
from plc.project import where

from plc import ast as A


@dataclass
class EnumType:
    name: str            # as spelled in the declaration
    values: list[str]    # as spelled, in declaration order (= their numbers)
    pos: Pos


@dataclass
class StFacts:
    enums: dict[str, EnumType] = field(default_factory=dict)               # by upper-case type name
    constants: dict[str, tuple[int, Pos]] = field(default_factory=dict)    # "POU.NAME" upper -> value
    cases: dict[str, dict[str, int]] = field(default_factory=dict)         # FUNCTION upper -> label upper -> value


def _int_value(expr) -> int | None:
    if isinstance(expr, A.IntLit):
        return expr.value
    if isinstance(expr, A.Unary) and expr.op == "-" and isinstance(expr.operand, A.IntLit):
        return -expr.operand.value
    return None


def st_facts(src_dir: Path, root: Path) -> StFacts:
    """Everything above from the .st files under src_dir.  Parse errors are ignored here (the compiler
    reports them); a file that does not parse contributes what the parser recovered."""
    facts = StFacts()
    for path in sorted(Path(src_dir).rglob("*.st")):
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError):
            continue
        try:
            name = where(path).relative_to(where(Path(root))).as_posix()
        except ValueError:
            name = str(path)
        tree = parse(text, name, Diagnostics())
        for item in tree.items:
            if isinstance(item, A.TypeBlock):
                for decl in item.decls:
                    if isinstance(decl.spec, A.EnumSpec):
                        texts = getattr(decl.spec, "texts", None) or [v for v, _p, _e in decl.spec.values]
                        facts.enums[decl.name.upper()] = EnumType(decl.text or decl.name, list(texts), decl.pos)
            elif isinstance(item, A.Pou):
                _pou_facts(item, facts)
    return facts


def _pou_facts(pou: A.Pou, facts: StFacts) -> None:
    for block in pou.blocks:
        if not block.constant:
            continue
        for d in block.decls:
            value = _int_value(d.init)
            if value is not None:
                facts.constants[f"{pou.name}.{d.name}".upper()] = (value, d.pos)
    if pou.kind != "FUNCTION":
        return
    table: dict[str, int] = {}
    for stmt in pou.body:
        if not isinstance(stmt, A.Case):
            continue
        for labels, body in stmt.arms:
            values = [_int_value(s.value) for s in body if isinstance(s, A.Assign)]
            values = [v for v in values if v is not None]
            for label in labels:        # E_Kind#Value or the bare Value (the form STruC++ takes too)
                value = label.lo.value if isinstance(label.lo, A.EnumLit) else \
                    label.lo.name if isinstance(label.lo, A.Name) else None
                if value is not None and values:
                    table[value.upper()] = values[0]
    if table:
        facts.cases[pou.name.upper()] = table


def st_enums(src_dir: Path, root: Path) -> dict[str, EnumType]:
    return st_facts(src_dir, root).enums
