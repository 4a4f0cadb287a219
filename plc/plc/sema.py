"""Resolver and semantic passes.

Input: the parsed files.  Output: a `Program` — the same AST with every
expression's `ty` and every name's `sym` filled in, plus the tables the C
generator needs.  The passes run in a fixed order:

1. declare   — collect every TYPE, POU and CONFIGURATION (duplicates reported);
2. types     — resolve type declarations (forward references are fine);
3. scopes    — build each POU's variable scope and check declarations;
4. bodies    — type-check statements and expressions with MATIEC's strictness;
5. configs   — tasks, program instances, globals, located variables.

Every problem becomes a diagnostic; checking goes on with an error type so one
mistake does not cascade.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import reduce

from . import ast as A
from . import types as T
from .diagnostics import Diagnostics, InternalError, Pos
from .stdfuncs import STD_FUNCS, conversion
from .symbols import FuncSym, Scope, VarSym
from .timelit import decode

LOCATION_SIZES = {"X": 1, "B": 8, "W": 16, "D": 32, "L": 64}
LOCATED_OK = {
    "X": ("BOOL",),
    "B": ("BYTE", "SINT", "USINT"),
    "W": ("WORD", "INT", "UINT"),
    "D": ("DWORD", "DINT", "UDINT", "REAL"),
    "L": ("LWORD", "LINT", "ULINT", "LREAL"),
}
TIME_KIND_TYPE = {"TIME": T.TIME, "TOD": T.TOD, "DATE": T.DATE, "DT": T.DT}


@dataclass(eq=False)
class TaskInfo:
    name: str
    interval_ns: int
    priority: int
    pos: Pos
    every: int = 1
    single: object = None      # VarSym of the BOOL global whose rising edge runs the task (SINGLE)


@dataclass(eq=False)
class InstanceInfo:
    name: str
    type: T.PouType
    task: TaskInfo | None
    resource: str
    pos: Pos
    cname: str = ""


@dataclass(eq=False)
class ConfigInfo:
    name: str
    decl: A.Configuration
    globals: dict[str, VarSym] = field(default_factory=dict)
    tasks: list[TaskInfo] = field(default_factory=list)
    instances: list[InstanceInfo] = field(default_factory=list)
    base_tick_ns: int = 0
    resources: list[str] = field(default_factory=list)


@dataclass(eq=False)
class Site:
    pos: Pos
    pou: str


@dataclass(eq=False)
class Program:
    files: list[A.SourceFile]
    types: dict[str, T.Type] = field(default_factory=dict)
    type_order: list[str] = field(default_factory=list)
    pous: dict[str, T.PouType] = field(default_factory=dict)      # FBs and PROGRAMs
    funcs: dict[str, FuncSym] = field(default_factory=dict)
    enum_values: dict[str, list[T.EnumType]] = field(default_factory=dict)
    type_inits: dict[int, object] = field(default_factory=dict)   # id(type) -> TYPE-level initial value
    configs: list[ConfigInfo] = field(default_factory=list)
    sites: list[Site] = field(default_factory=list)
    array_types: list[T.ArrayType] = field(default_factory=list)
    builtin_files: set[str] = field(default_factory=set)

    def site(self, pos: Pos, pou: str) -> int:
        self.sites.append(Site(pos, pou))
        return len(self.sites) - 1


class LoopCtx:
    def __init__(self) -> None:
        self.loop_depth = 0
        self.for_vars: list[VarSym] = []


class Analyzer:
    def __init__(self, files: list[A.SourceFile], diags: Diagnostics, builtin_files: set[str] | None = None,
                 test_build: bool = False):
        self.files = files
        self.d = diags
        self.prog = Program(files)
        self.prog.builtin_files = builtin_files or set()
        self.type_decls: dict[str, A.TypeDecl] = {}
        self.pou_decls: dict[str, A.Pou] = {}
        self.resolving: set[str] = set()
        self.current_pou: A.Pou | None = None
        self.test_build = test_build
        self.global_scope: dict[str, VarSym] = {}
        self.locations: dict[tuple, A.VarDecl] = {}      # (scope, (area, size, parts)) -> first declaration
        self.output_owner: dict[tuple, tuple[str, A.VarDecl, str]] = {}   # %Q address -> first scope

    # ================================================================ helpers ==
    def err(self, pos: Pos, msg: str, hint: str | None = None, code: str = "semantic") -> None:
        self.d.error(pos, msg, hint, code)

    def warn(self, pos: Pos, msg: str, hint: str | None = None, code: str = "semantic") -> None:
        self.d.warning(pos, msg, hint, code)

    def port(self, pos: Pos, msg: str, hint: str | None = None, code: str = "portability") -> None:
        if pos.file in self.prog.builtin_files:
            return
        self.d.portable(pos, msg, hint, code)

    def in_builtin(self) -> bool:
        return self.current_pou is not None and self.current_pou.pos.file in self.prog.builtin_files

    # ================================================================ pass 1 ==
    def run(self) -> Program:
        self.declare()
        self.resolve_types()
        self.build_scopes()
        for cfg in (i for f in self.files for i in f.items if isinstance(i, A.Configuration)):
            self.configuration(cfg)
        self.bind_externals()
        self.check_bodies()
        return self.prog

    def declare(self) -> None:
        seen: dict[str, Pos] = {}

        def claim(name: str, text: str, pos: Pos, what: str) -> bool:
            if name in seen:
                first = seen[name]
                self.err(pos, f"duplicate {what} name '{text}'", f"first declared at {first}")
                return False
            if name in T.ELEMENTARY or name in T.UNSUPPORTED or name in T.GENERIC:
                self.err(pos, f"'{text}' is the name of an elementary type")
                return False
            if name in STD_FUNCS or conversion(name) is not None:
                if pos.file not in self.prog.builtin_files:
                    self.err(pos, f"'{text}' is the name of a standard function")
                    return False
            seen[name] = pos
            return True

        for f in self.files:
            for item in f.items:
                if isinstance(item, A.TypeBlock):
                    for td in item.decls:
                        if claim(td.name, td.text, td.pos, "type"):
                            self.type_decls[td.name] = td
                elif isinstance(item, A.Pou):
                    if claim(item.name, item.text, item.pos, "POU"):
                        self.pou_decls[item.name] = item
                elif isinstance(item, A.Configuration):
                    claim(item.name, item.text, item.pos, "CONFIGURATION")
                elif isinstance(item, A.VarBlock):
                    # VAR_GLOBAL outside a configuration (extension): treat as globals of every configuration
                    for vd in item.decls:
                        self.global_scope.setdefault(vd.name, None)  # filled in configuration()
        # POU types are known before any type is resolved (FB instances as struct members are errors)
        for name, pou in self.pou_decls.items():
            if pou.kind in ("FUNCTION_BLOCK", "PROGRAM"):
                self.prog.pous[name] = T.PouType(name, pou, pou.kind, builtin=pou.pos.file in self.prog.builtin_files)

    # ================================================================ pass 2 ==
    def resolve_types(self) -> None:
        for name in self.type_decls:
            self.named_type(name, self.type_decls[name].pos)

    def named_type(self, name: str, pos: Pos) -> T.Type:
        if name in self.prog.types:
            return self.prog.types[name]
        td = self.type_decls.get(name)
        if td is None:
            return T.ERROR
        if name in self.resolving:
            self.err(td.pos, f"type '{td.text}' is defined in terms of itself")
            return T.ERROR
        self.resolving.add(name)
        try:
            t = self.type_spec(td.spec, name_for=td)
        finally:
            self.resolving.discard(name)
        if td.init is not None and not isinstance(t, T.ErrorType):
            if isinstance(t, T.StructType):
                self.err(td.pos, "a STRUCT type takes initial values per member, not for the whole type")
            else:
                self.check_init(td.init, t)
                if not isinstance(td.spec, A.TypeRef):
                    t = self.with_default(t, td.init)
                # an alias (TYPE Speed : INT := 5) shares its type object: the initial
                # value belongs to the name and is applied where the name is used (alias_init)
        self.prog.types[name] = t
        self.prog.type_order.append(name)
        return t

    def alias_init(self, spec):
        """Initial value a declaration of type `spec` inherits from a TYPE alias chain, if any."""
        seen = set()
        while isinstance(spec, A.TypeRef) and spec.name in self.type_decls and spec.name not in seen:
            seen.add(spec.name)
            td = self.type_decls[spec.name]
            if td.init is not None:
                return td.init if isinstance(td.spec, A.TypeRef) else None
            spec = td.spec
        return None

    def with_default(self, t: T.Type, init) -> T.Type:
        """Types declared with an initial value keep it (TYPE Speed : INT := 5; END_TYPE)."""
        self.prog.type_inits[id(t)] = init
        return t

    def type_ref(self, ref: A.TypeRef) -> T.Type:
        name = ref.name
        if name in T.ELEMENTARY:
            if name == "STRING" and ref.length is not None:
                n = self.const_int(ref.length)
                self.port(ref.pos, "STRING[n] is not supported by OpenPLC (a bare declaration crashes iec2c)",
                          "use plain STRING (126 characters)", code="portability.string-length")
                if n is None or not 1 <= n <= 126:
                    self.err(ref.length.pos, "string length must be a constant between 1 and 126")
                    return T.STRING
                return T.StringType(n)
            return T.ELEMENTARY[name]
        if name in T.UNSUPPORTED:
            self.err(ref.pos, T.UNSUPPORTED[name])
            return T.ERROR
        if name in self.type_decls:
            return self.named_type(name, ref.pos)
        if name in self.prog.pous:
            return self.prog.pous[name]
        if name in self.pou_decls:
            self.err(ref.pos, f"'{ref.text}' is a FUNCTION, not a type")
            return T.ERROR
        self.err(ref.pos, f"unknown type '{ref.text}'", self.suggest(name, list(self.type_decls) +
                                                                     list(self.prog.pous) + list(T.ELEMENTARY)))
        return T.ERROR

    def suggest(self, name: str, candidates) -> str | None:
        import difflib
        close = difflib.get_close_matches(name, list(candidates), n=1, cutoff=0.75)
        return f"did you mean '{close[0]}'?" if close else None

    def type_spec(self, spec, name_for: A.TypeDecl | None = None) -> T.Type:
        if isinstance(spec, A.TypeRef):
            return self.type_ref(spec)
        if isinstance(spec, A.EnumSpec):
            if name_for is None:
                self.port(spec.pos, "anonymous enumeration in a variable declaration",
                          "declare the enumeration in a TYPE block", code="portability.anon-enum")
            name = name_for.name if name_for else f"ENUM_{spec.pos.line}_{spec.pos.col}"
            vals = []
            for v, pos, explicit in spec.values:
                if explicit is not None:
                    self.port(pos, "enumeration values with explicit numbers are not accepted by MATIEC",
                              "remove ':= n'", code="portability.enum-value")
                if v in vals:
                    self.err(pos, f"duplicate enumeration value '{v}'")
                    continue
                if v == "ON":
                    self.port(pos, "'ON' is reserved in MATIEC and cannot be an enumeration value",
                              code="portability.enum-on")
                vals.append(v)
            if spec.base is not None:
                self.port(spec.pos, "enumerations with a base type are IEC edition 3", code="portability.enum-base")
            et = T.EnumType(name, vals)
            for v in vals:
                self.prog.enum_values.setdefault(v, []).append(et)
            return et
        if isinstance(spec, A.SubrangeSpec):
            base = self.type_ref(spec.base)
            b = T.resolve_base(base)
            lo, hi = self.const_int(spec.lo), self.const_int(spec.hi)
            if not (isinstance(b, T.Elementary) and b.is_int):
                if not isinstance(b, T.ErrorType):
                    self.err(spec.pos, f"a subrange needs an integer base type, not {base}")
                return T.ERROR
            if lo is None or hi is None:
                self.err(spec.pos, "subrange bounds must be constant integers")
                return b
            if lo > hi or lo < b.lo or hi > b.hi:
                self.err(spec.pos, f"subrange {lo}..{hi} does not fit {b.name}")
                return b
            return T.SubrangeType(name_for.name if name_for else f"{b.name}({lo}..{hi})", b, lo, hi)
        if isinstance(spec, A.ArraySpec):
            dims = []
            for lo_e, hi_e in spec.dims:
                for e in (lo_e, hi_e):
                    n = e if isinstance(e, A.Name) else e.operand if isinstance(e, A.Unary) else None
                    if isinstance(n, A.Name) and not self.is_external_constant(n.name):
                        # (a VAR_GLOBAL CONSTANT reached through VAR_EXTERNAL CONSTANT is fine with iec2c -a)
                        self.port(e.pos, "a named constant as an array bound is not accepted by MATIEC",
                                  "write the bound as a literal", code="portability.array-bound")
                lo, hi = self.const_int(lo_e), self.const_int(hi_e)
                if lo is None or hi is None:
                    self.err(lo_e.pos, "array bounds must be constant integers")
                    return T.ERROR
                if lo > hi:
                    self.err(lo_e.pos, f"array bounds {lo}..{hi} are reversed")
                    return T.ERROR
                dims.append((lo, hi))
            elem = self.type_spec(spec.elem)
            if isinstance(elem, T.PouType):
                self.port(spec.pos, "arrays of function block instances are not supported by MATIEC",
                          code="portability.fb-array")
                self.err(spec.pos, "arrays of function block instances are not supported")
                return T.ERROR
            if isinstance(elem, T.ErrorType):
                return T.ERROR
            at = T.ArrayType(dims, elem)
            for existing in self.prog.array_types:
                if existing.dims == at.dims and existing.elem is at.elem:
                    return existing
            at.cname = f"ARR{len(self.prog.array_types)}"
            self.prog.array_types.append(at)
            if isinstance(T.resolve_base(elem), T.ArrayType):
                self.port(spec.pos, "arrays of arrays break OpenPLC's C build", "use a 2-D array ARRAY[a..b, c..d]",
                          code="portability.array-of-array")
            if at.count() > 1_000_000:
                self.err(spec.pos, f"array of {at.count()} elements is too large")
            return at
        if isinstance(spec, A.StructSpec):
            if name_for is None:
                self.port(spec.pos, "anonymous STRUCT in a variable declaration", "declare it in a TYPE block",
                          code="portability.anon-struct")
            st = T.StructType(name_for.name if name_for else f"STRUCT_{spec.pos.line}_{spec.pos.col}",
                              decl=name_for)
            for m in spec.members:
                if m.name in st.members:
                    self.err(m.pos, f"duplicate member '{m.text}' in STRUCT")
                    continue
                mt = self.type_spec(m.spec)
                if getattr(mt, "name", "").upper() == m.name.upper():
                    self.port(m.pos, f"member '{m.text}' is named like its type: OpenPLC's g++ rejects the C "
                              "that MATIEC makes of it", "give the member another name",
                              code="portability.member-named-like-type")
                if isinstance(mt, T.PouType):
                    self.err(m.pos, "function block instances inside a STRUCT are not supported by MATIEC")
                    mt = T.ERROR
                if m.init is not None and not isinstance(mt, T.ErrorType):
                    self.check_init(m.init, mt)
                st.members[m.name] = T.StructMemberT(m.name, mt, m.init if m.init is not None
                                                     else self.alias_init(m.spec), m.pos)
            return st
        if isinstance(spec, A.PointerSpec):
            self.err(spec.pos, f"{spec.kind} is not supported (MATIEC has no usable pointers)",
                     code="portability.pointer")
            return T.ERROR
        return T.ERROR

    # ============================================================ constants ==
    def const_value(self, e: A.Expr):
        """Fold a constant expression: int, float, bool, or None if not constant."""
        if isinstance(e, A.IntLit):
            return e.value
        if isinstance(e, A.RealLit):
            return e.value
        if isinstance(e, A.BoolLit):
            return e.value
        if isinstance(e, A.TimeLit):
            return decode(e.kind, e.text)
        if isinstance(e, A.Name):
            sym = e.sym or self.lookup_const(e.name)
            if isinstance(sym, VarSym) and sym.constant and sym.const_value is not None:
                return sym.const_value
            if isinstance(sym, VarSym) and sym.constant and sym.section == "VAR_EXTERNAL":
                return self.global_constant(e.name)
            return None
        if isinstance(e, A.Unary):
            v = self.const_value(e.operand)
            if v is None:
                return None
            if e.op == "-" and not isinstance(v, bool):
                return -v
            if e.op == "+":
                return v
            if e.op == "NOT" and isinstance(v, bool):
                return not v
            return None
        if isinstance(e, A.Binary):
            a, b = self.const_value(e.left), self.const_value(e.right)
            if a is None or b is None or isinstance(a, bool) or isinstance(b, bool):
                return None
            try:
                if e.op == "+":
                    return a + b
                if e.op == "-":
                    return a - b
                if e.op == "*":
                    return a * b
                if e.op == "/" and b != 0:
                    return int(a / b) if isinstance(a, int) and isinstance(b, int) else a / b
                if e.op == "MOD" and isinstance(a, int) and isinstance(b, int):
                    return 0 if b == 0 else int(math.fmod(a, b))
            except (OverflowError, ValueError):
                return None
        return None

    def const_int(self, e: A.Expr) -> int | None:
        v = self.const_value(e)
        return v if isinstance(v, int) and not isinstance(v, bool) else None

    def is_external_constant(self, name: str) -> bool:
        sym = self.lookup_const(name)
        return isinstance(sym, VarSym) and sym.constant and sym.section == "VAR_EXTERNAL"

    def global_constant(self, name: str):
        """Value of the VAR_GLOBAL CONSTANT `name`, read from its declaration: a VAR_EXTERNAL CONSTANT
        may bound an array before the configuration itself has been analysed."""
        busy = self.__dict__.setdefault("_globals_in_progress", set())
        if name in busy:
            return None
        busy.add(name)
        try:
            for f in self.files:
                for cfg in (i for i in f.items if isinstance(i, A.Configuration)):
                    for b in [*cfg.globals, *(b for r in cfg.resources for b in r.globals)]:
                        for d in b.decls if b.constant else []:
                            if d.name == name and isinstance(d.init, A.Expr):
                                return self.const_value(d.init)
            return None
        finally:
            busy.discard(name)

    def lookup_const(self, name: str):
        scope = getattr(self, "scope", None)
        if scope is not None:
            s = scope.lookup(name)
            if s is not None:
                return s
        return None

    # ================================================================ pass 3 ==
    def build_scopes(self) -> None:
        for name, pou in self.pou_decls.items():
            self.current_pou = pou
            scope = Scope(name, pou.kind)
            self.scope = scope
            if pou.kind == "FUNCTION":
                ret = self.type_ref(pou.ret) if pou.ret else T.ERROR
                if isinstance(ret, T.PouType):
                    self.err(pou.ret.pos, "a FUNCTION cannot return a function block")
                    ret = T.ERROR
                fs = FuncSym(name, pou.text, pou, ret, scope, builtin=pou.pos.file in self.prog.builtin_files)
                self.prog.funcs[name] = fs
            else:
                self.prog.pous[name].scope = scope
            for block in pou.blocks:
                self.var_block(block, scope, pou)
            self.current_pou = None
            self.scope = None

    def var_block(self, block: A.VarBlock, scope: Scope, pou: A.Pou | None) -> None:
        kind = pou.kind if pou else "CONFIGURATION"
        sec = block.section
        allowed = {
            "FUNCTION": ("VAR", "VAR_INPUT", "VAR_OUTPUT", "VAR_IN_OUT", "VAR_TEMP"),
            "FUNCTION_BLOCK": ("VAR", "VAR_INPUT", "VAR_OUTPUT", "VAR_IN_OUT", "VAR_EXTERNAL", "VAR_TEMP"),
            "PROGRAM": ("VAR", "VAR_INPUT", "VAR_OUTPUT", "VAR_IN_OUT", "VAR_EXTERNAL", "VAR_TEMP"),
            "CONFIGURATION": ("VAR_GLOBAL",),
        }[kind]
        if sec not in allowed:
            if sec == "VAR_EXTERNAL" and kind == "FUNCTION":
                self.err(block.pos, "a FUNCTION cannot use VAR_EXTERNAL", "pass the value as an input")
            elif sec == "VAR_GLOBAL":
                self.err(block.pos, "VAR_GLOBAL belongs in a CONFIGURATION or RESOURCE")
            else:
                self.err(block.pos, f"{sec} is not allowed in a {kind}")
            return
        if block.retain and kind == "FUNCTION":
            self.err(block.pos, "a FUNCTION has no memory: RETAIN is not allowed")
        if block.constant and sec in ("VAR_INPUT", "VAR_OUTPUT", "VAR_IN_OUT", "VAR_TEMP"):
            self.err(block.pos, f"{sec} cannot be CONSTANT")
        located = [d for d in block.decls if d.location is not None]
        if located and len(located) != len(block.decls):
            self.port(block.pos, "a VAR block mixing located and unlocated variables is rejected by MATIEC",
                      "put the located variables in a VAR block of their own", code="portability.mixed-located")
        for d in block.decls:
            self.declare_var(d, scope, pou, block)

    def declare_var(self, d: A.VarDecl, scope: Scope, pou: A.Pou | None, block: A.VarBlock) -> VarSym | None:
        if d.name in scope.vars:
            first = scope.vars[d.name]
            self.err(d.pos, f"duplicate variable '{d.text}'", f"first declared at {first.pos}")
            return None
        if pou is not None and d.name == pou.name and pou.kind == "FUNCTION":
            self.err(d.pos, f"'{d.text}' is the name of the FUNCTION itself (its result)")
            return None
        t = self.type_spec(d.spec)
        if isinstance(d.spec, A.SubrangeSpec) and isinstance(t, T.SubrangeType) and d.init is None and t.lo != 0 \
                and d.section not in ("VAR_IN_OUT", "VAR_EXTERNAL"):
            self.port(d.pos, f"MATIEC starts an inline subrange variable at 0, not at its lower bound {t.lo}",
                      "give it an initial value, or declare the subrange as a TYPE", code="portability.subrange-default")
        if isinstance(t, T.PouType) and d.section == "VAR_GLOBAL":
            self.port(d.pos, "function block instances in VAR_GLOBAL break OpenPLC's C build",
                      "declare the instance in the PROGRAM", code="portability.global-fb")
        if isinstance(t, T.PouType):
            if t.kind == "PROGRAM":
                self.err(d.pos, "a PROGRAM cannot be instantiated inside a POU", "instantiate it in a RESOURCE")
                t = T.ERROR
            elif pou is not None and pou.kind == "FUNCTION":
                self.err(d.pos, "a FUNCTION cannot contain function block instances")
                t = T.ERROR
            elif d.section == "VAR_IN_OUT":
                self.port(d.pos, "a function block instance passed as VAR_IN_OUT is not supported by MATIEC",
                          code="portability.fb-inout")
            elif d.section in ("VAR_INPUT", "VAR_OUTPUT"):
                self.err(d.pos, f"a function block instance cannot be a {d.section}")
                t = T.ERROR
            if d.init is not None and not isinstance(t, T.ErrorType):
                self.check_instance_init(d.init, t)
        if d.location is not None:
            self.check_location(d, t, pou)
        if d.init is not None and not isinstance(t, (T.ErrorType, T.PouType)):
            if d.section in ("VAR_IN_OUT", "VAR_EXTERNAL"):
                self.err(d.pos, f"{d.section} variables cannot have an initial value")
            else:
                self.check_init(d.init, t)
        if block.constant and d.init is None and d.section != "VAR_EXTERNAL":
            self.err(d.pos, f"CONSTANT '{d.text}' needs an initial value")
        init = d.init
        if init is None and d.section not in ("VAR_IN_OUT", "VAR_EXTERNAL"):
            init = self.alias_init(d.spec)
        sym = VarSym(d.name, d.text, t, d.section, d.pos, d, block.constant, block.retain, d.location, init,
                     owner=pou.name if pou else "")
        if block.constant and d.init is not None and isinstance(d.init, A.Expr):
            sym.const_value = self.const_value(d.init)
        scope.vars[d.name] = sym
        return sym

    def check_location(self, d: A.VarDecl, t: T.Type, pou: A.Pou | None) -> None:
        loc = d.location
        # one address, one variable within a scope (a PROGRAM, or the global variables); as in MATIEC, PROGRAMs
        # may each locate a variable at the same address: they share it (an input read by several programs)
        scope = pou.name if pou is not None else ""
        key = (loc.area, loc.size, tuple(loc.parts))
        first = self.locations.setdefault((scope, key), d)
        if first is not d:
            self.err(loc.pos, f"{loc.text} is already the location of '{first.text}'",
                     f"declared at {first.pos}; one address, one variable", code="located-duplicate")
        elif loc.area == "Q":
            shown = pou.text if pou is not None else ""
            other = self.output_owner.setdefault(key, (scope, d, shown))
            if other[0] != scope:
                self.warn(loc.pos, f"{loc.text} is also the location of '{other[1].text}' "
                          f"({'PROGRAM ' + other[2] if other[2] else 'a global variable'}): both write this output, "
                          "the program that runs last in the scan wins",
                          f"declared at {other[1].pos}", code="located-shared-output")
        if pou is not None and pou.kind == "FUNCTION_BLOCK":
            self.err(loc.pos, "located variables are not allowed inside a FUNCTION_BLOCK (iec2c crashes on them)",
                     "locate variables in the PROGRAM or in VAR_GLOBAL", code="located-in-fb")
        if pou is not None and pou.kind == "FUNCTION":
            self.err(loc.pos, "located variables are not allowed inside a FUNCTION")
        b = T.resolve_base(t)
        if isinstance(b, T.ErrorType):
            return
        name = b.name if isinstance(b, T.Elementary) else None
        if name not in LOCATED_OK[loc.size]:
            self.err(loc.pos, f"{loc.text} is a {LOCATION_SIZES[loc.size]}-bit location but '{d.text}' is {t}",
                     f"{loc.size} locations hold {', '.join(LOCATED_OK[loc.size])}", code="located-type")
        if loc.size == "X":
            if len(loc.parts) != 2 or not (0 <= loc.parts[1] <= 7):
                self.err(loc.pos, f"bit address {loc.text} must be written %{loc.area}Xbyte.bit with bit 0..7")
        elif len(loc.parts) != 1:
            self.err(loc.pos, f"{loc.text}: only bit addresses have a '.' part")

    # -------------------------------------------------------------- initialisers --
    def check_instance_init(self, init, t: T.PouType) -> None:
        """`timer : TON := (PT := T#2s);` presets members of a function block instance (MATIEC accepts it)."""
        if not isinstance(init, A.StructInit):
            self.err(init.pos if hasattr(init, "pos") else t.pou.pos,
                     "a function block instance can only be initialised with (member := value, ...)")
            return
        for name, pos, v in init.fields:
            m = t.scope.vars.get(name) if t.scope is not None else None
            if m is None or m.section in ("VAR_IN_OUT", "VAR_EXTERNAL", "VAR_TEMP"):
                self.err(pos, f"{t.name} has no member '{name}' that can be initialised")
                continue
            self.check_init(v, m.type)

    def check_init(self, init, t: T.Type) -> None:
        b = T.resolve_base(t)
        if isinstance(init, A.ArrayInit):
            if not isinstance(b, T.ArrayType):
                self.err(init.pos, f"an array initialiser [...] cannot initialise {t}")
                return
            if isinstance(T.resolve_base(b.elem), T.StructType):
                self.port(init.pos, "initialisers of arrays of structures break OpenPLC's C build",
                          "initialise the elements in code", code="portability.struct-array-init")
            count = 0
            elem = b.elem
            for rep, v in init.items:
                n = 1
                if rep is not None:
                    n = self.const_int(rep) or 0
                    if n <= 0:
                        self.err(rep.pos, "repeat count must be a positive integer")
                count += n
                if v is not None:
                    # a nested array element may be given flat, element by element
                    flat = isinstance(T.resolve_base(elem), T.ArrayType) and not isinstance(v, A.ArrayInit)
                    self.check_init(v, T.resolve_base(elem).elem if flat else elem)
            total = b.count()
            if isinstance(T.resolve_base(b.elem), T.ArrayType):
                total = b.count()
            if count > total and not isinstance(T.resolve_base(b.elem), T.ArrayType):
                self.err(init.pos, f"{count} initial values for an array of {total} elements")
            return
        if isinstance(init, A.StructInit):
            if not isinstance(b, T.StructType):
                self.err(init.pos, f"a structure initialiser (...) cannot initialise {t}")
                return
            for name, pos, v in init.fields:
                m = b.members.get(name)
                if m is None:
                    self.err(pos, f"'{b.name}' has no member '{name}'")
                    continue
                self.check_init(v, m.type)
            return
        # an expression: must be constant
        if isinstance(b, (T.ArrayType, T.StructType)):
            self.err(init.pos, f"{t} needs an initialiser in {'[...]' if isinstance(b, T.ArrayType) else '(...)'}")
            return
        saved = getattr(self, "scope", None)
        ty = self.expr(init, saved, t, for_init=True)
        self.assign_compat(init, ty, t, init.pos, "initial value")
        if not self.is_constant_expr(init):
            self.err(init.pos, "an initial value must be a constant expression")

    def is_constant_expr(self, e: A.Expr) -> bool:
        if isinstance(e, (A.IntLit, A.RealLit, A.BoolLit, A.StrLit, A.TimeLit, A.EnumLit)):
            return True
        if isinstance(e, A.Name):
            return isinstance(e.sym, tuple) or (isinstance(e.sym, VarSym) and e.sym.constant)
        if isinstance(e, A.Unary):
            return self.is_constant_expr(e.operand)
        if isinstance(e, A.Binary):
            return self.is_constant_expr(e.left) and self.is_constant_expr(e.right)
        return False

    # ============================================================ configuration ==
    def configuration(self, cfg: A.Configuration) -> None:
        info = ConfigInfo(cfg.name, cfg)
        self.prog.configs.append(info)
        gscope = Scope(cfg.name, "CONFIGURATION")
        self.scope = gscope
        for block in cfg.globals:
            self.var_block(block, gscope, None)
        tasks: dict[str, TaskInfo] = {}
        for res in cfg.resources:
            info.resources.append(res.name)
            for block in res.globals:
                self.var_block(block, gscope, None)
            for td in res.tasks:
                if td.name in tasks:
                    self.err(td.pos, f"duplicate task '{td.text}'")
                    continue
                single = None
                if td.single is not None:
                    st = self.expr(td.single, gscope, T.BOOL)
                    sym = getattr(td.single, "sym", None)
                    if not isinstance(td.single, A.Name) or not isinstance(sym, VarSym) or not T.is_elem(st, "bool"):
                        self.err(td.single.pos, "SINGLE needs a BOOL global variable",
                                 "TASK ev(SINGLE := trigger, PRIORITY := 1); with trigger in VAR_GLOBAL")
                    else:
                        single = sym
                interval = 0
                if td.interval is not None:
                    self.expr(td.interval, gscope, T.TIME)
                    v = self.const_value(td.interval)
                    if not isinstance(td.interval, A.TimeLit) or v is None or v <= 0:
                        self.err(td.interval.pos, "INTERVAL must be a positive TIME literal", "INTERVAL := T#10ms")
                    elif single is None:       # as MATIEC, SINGLE wins: the task runs on rising edges only
                        interval = v
                elif td.single is None:
                    self.err(td.pos, f"task '{td.text}' has neither INTERVAL nor SINGLE",
                             "TASK t(INTERVAL := T#10ms, PRIORITY := 0);")
                prio = 0
                if td.priority is not None:
                    p = self.const_int(td.priority)
                    if p is None or p < 0:
                        self.err(td.priority.pos, "PRIORITY must be a non-negative integer")
                    else:
                        prio = p
                ti = TaskInfo(td.name, interval, prio, td.pos, single=single)
                tasks[td.name] = ti
                info.tasks.append(ti)
            for pi in res.programs:
                pt = self.prog.pous.get(pi.type_name)
                if pt is None or pt.kind != "PROGRAM":
                    self.err(pi.pos, f"unknown PROGRAM '{pi.type_text}'",
                             self.suggest(pi.type_name, [n for n, p in self.prog.pous.items() if p.kind == "PROGRAM"]))
                    continue
                task = None
                if pi.task is None:
                    self.port(pi.pos, f"program instance '{pi.text}' has no task: MATIEC rejects it",
                              "PROGRAM inst WITH task : Type;", code="portability.no-task")
                if not res.name:
                    self.port(pi.pos, "TASK and PROGRAM directly in the CONFIGURATION are rejected by MATIEC",
                              "put them in RESOURCE Res0 ON PLC", code="portability.no-resource")
                if pi.task is not None:
                    task = tasks.get(pi.task)
                    if task is None:
                        self.err(pi.pos, f"unknown task '{pi.task}'")
                if pi.args:
                    self.err(pi.args[0].pos, "program instance parameters are not supported",
                             "connect the program through VAR_EXTERNAL / located variables")
                if any(i.name == pi.name for i in info.instances) or pi.name in gscope.vars:
                    self.err(pi.pos, f"duplicate program instance '{pi.text}'")
                    continue
                info.instances.append(InstanceInfo(pi.name, pt, task, res.name, pi.pos))
        intervals = [t.interval_ns for t in info.tasks if t.interval_ns > 0]
        info.base_tick_ns = reduce(math.gcd, intervals) if intervals else 0
        if not intervals and any(t.single is not None for t in info.tasks):
            self.err(cfg.pos, "a configuration needs at least one periodic task (INTERVAL) to set the scan tick")
        for t in info.tasks:
            if info.base_tick_ns and t.interval_ns:
                t.every = t.interval_ns // info.base_tick_ns
        info.globals = gscope.vars
        for v in gscope.vars.values():
            self.global_scope[v.name] = v
        self.scope = None

    def bind_externals(self) -> None:
        for pou_name, pou in self.pou_decls.items():
            scope = self.prog.funcs[pou_name].scope if pou.kind == "FUNCTION" else self.prog.pous[pou_name].scope
            for v in scope.vars.values():
                if v.section != "VAR_EXTERNAL":
                    continue
                g = self.global_scope.get(v.name)
                if g is None:
                    if self.prog.configs:
                        self.err(v.pos, f"VAR_EXTERNAL '{v.text}' has no matching VAR_GLOBAL in the configuration")
                    continue
                if not T.same_type(g.type, v.type) and not isinstance(v.type, T.ErrorType):
                    self.err(v.pos, f"VAR_EXTERNAL '{v.text}' is {v.type} but the VAR_GLOBAL is {g.type}",
                             f"declared at {g.pos}")
                if g.constant and not v.constant:
                    self.err(v.pos, f"VAR_EXTERNAL '{v.text}' must be CONSTANT: the VAR_GLOBAL is CONSTANT")
                v.global_sym = g

    # ================================================================ pass 4 ==
    def check_bodies(self) -> None:
        for name, pou in self.pou_decls.items():
            self.current_pou = pou
            if pou.kind == "FUNCTION":
                self.scope = self.prog.funcs[name].scope
                self.func = self.prog.funcs[name]
            else:
                self.scope = self.prog.pous[name].scope
                self.func = None
            self.loop = LoopCtx()
            self.stmts(pou.body)
            self.current_pou = None

    def stmts(self, body: list[A.Stmt]) -> None:
        for s in body:
            self.stmt(s)

    def stmt(self, s: A.Stmt) -> None:
        if isinstance(s, A.Assign):
            self.assign(s)
        elif isinstance(s, A.CallStmt):
            self.call_stmt(s)
        elif isinstance(s, A.If):
            for cond, body in s.branches:
                self.condition(cond, "IF")
                self.stmts(body)
            if s.orelse is not None:
                self.stmts(s.orelse)
        elif isinstance(s, A.Case):
            self.case(s)
        elif isinstance(s, A.For):
            self.for_stmt(s)
        elif isinstance(s, A.While):
            self.condition(s.cond, "WHILE")
            self.loop.loop_depth += 1
            self.stmts(s.body)
            self.loop.loop_depth -= 1
        elif isinstance(s, A.Repeat):
            self.loop.loop_depth += 1
            self.stmts(s.body)
            self.loop.loop_depth -= 1
            self.condition(s.cond, "UNTIL")
        elif isinstance(s, (A.Exit, A.Continue)):
            if self.loop.loop_depth == 0:
                self.err(s.pos, f"{'EXIT' if isinstance(s, A.Exit) else 'CONTINUE'} outside a loop")
        elif isinstance(s, (A.Return, A.Empty)):
            pass
        else:
            raise InternalError(s.pos, f"semantic analysis does not handle the statement {type(s).__name__}")

    def condition(self, e: A.Expr, what: str) -> None:
        t = self.expr(e, self.scope, T.BOOL)
        if not isinstance(t, T.ErrorType) and not T.is_elem(t, "bool"):
            self.err(e.pos, f"{what} condition must be BOOL, not {t}")

    def assign(self, s: A.Assign) -> None:
        tt = self.lvalue(s.target, "assign to")
        vt = self.expr(s.value, self.scope, tt if not isinstance(tt, T.ErrorType) else None)
        if isinstance(T.resolve_base(tt), T.PouType):
            self.err(s.pos, "function block instances cannot be assigned")
            return
        self.assign_compat(s.value, vt, tt, s.value.pos, "assignment")

    def lvalue(self, target: A.Expr, verb: str) -> T.Type:
        """Check an assignment target; report writes to constants, inputs and the FOR variable."""
        t = self.expr(target, self.scope, None, lvalue=True)
        root = target
        path_through_instance = False
        while isinstance(root, (A.Member, A.Index, A.BitAccess)):
            if isinstance(root, A.Member) and isinstance(T.resolve_base(root.base.ty or T.ERROR), T.PouType):
                inst_t = T.resolve_base(root.base.ty)
                member = inst_t.scope.lookup(root.name) if inst_t.scope else None
                if member is not None and member.section in ("VAR_OUTPUT",):
                    self.err(root.pos, f"cannot {verb} output '{root.text or root.name}' of an instance from outside",
                             "outputs are written by the function block itself")
                elif member is not None and member.section in ("VAR", "VAR_TEMP", "VAR_EXTERNAL"):
                    self.err(root.pos, f"'{root.text or root.name}' is internal to {inst_t.name} and cannot be written from outside")
                path_through_instance = True
            root = root.base
        if isinstance(root, A.Direct):
            if root.area == "I":
                self.err(root.pos, f"cannot {verb} the input {root.text}")
            return t
        if isinstance(root, A.Name) and isinstance(root.sym, VarSym):
            sym = root.sym
            if sym.constant or (sym.global_sym is not None and sym.global_sym.constant):
                self.err(target.pos, f"cannot {verb} CONSTANT '{sym.text}'")
            elif sym.location is not None and sym.location.area == "I" and not path_through_instance:
                self.err(target.pos, f"cannot {verb} '{sym.text}': it is located at the input {sym.location.text}")
            elif sym.section == "VAR_INPUT" and not path_through_instance and target is root \
                    and self.current_pou is not None and self.current_pou.kind != "FUNCTION" and not self.in_builtin():
                self.err(target.pos, f"cannot {verb} input '{sym.text}' inside its own function block",
                         "copy it to a local variable first")
            if sym in self.loop.for_vars:
                self.err(target.pos, f"cannot {verb} the FOR control variable '{sym.text}' inside its loop")
        elif isinstance(root, A.Name) and root.sym == "EN":
            self.err(target.pos, f"cannot {verb} EN: it is an input")
        elif isinstance(root, A.Name) and isinstance(root.sym, tuple):
            self.err(target.pos, f"cannot {verb} the enumeration value '{root.name}'")
        return t

    def case(self, s: A.Case) -> None:
        st = self.expr(s.selector, self.scope, None)
        b = T.resolve_base(st)
        if isinstance(b, T.LiteralType):
            b = T.DINT
        if not (isinstance(b, T.EnumType) or (isinstance(b, T.Elementary) and b.cat in ("int", "uint", "bit"))) \
                and not isinstance(b, T.ErrorType):
            self.err(s.selector.pos, f"CASE selector must be an integer or enumeration, not {st}")
            b = T.ERROR
        seen: list[tuple[int, int, Pos]] = []
        for labels, body in s.arms:
            for lab in labels:
                values = []
                for e in (lab.lo, lab.hi):
                    if e is None:
                        continue
                    lt = self.expr(e, self.scope, b if not isinstance(b, T.ErrorType) else None)
                    if isinstance(b, T.ErrorType) or isinstance(lt, T.ErrorType):
                        continue
                    if isinstance(b, T.EnumType):
                        if not (isinstance(e, (A.Name, A.EnumLit)) and isinstance(e.sym, tuple)
                                and e.sym[0] is b) and not (isinstance(e, A.EnumLit) and lt is b):
                            self.err(e.pos, f"CASE label must be a value of {b.name}")
                            continue
                        values.append(b.values.index(e.sym[1] if isinstance(e, A.Name) else e.value))
                    else:
                        if not self.is_constant_expr(e):
                            self.err(e.pos, "CASE labels must be constants")
                            continue
                        if isinstance(e, A.Name) or (isinstance(e, A.Unary) and isinstance(e.operand, A.Name)):
                            self.port(e.pos, "a named constant as a CASE label is rejected by MATIEC",
                                      "write the value as a literal", code="portability.case-constant")
                        if not (isinstance(T.resolve_base(lt), T.LiteralType) or T.same_type(lt, b)):
                            self.err(e.pos, f"CASE label of type {lt} does not match the selector type {b}")
                            continue
                        v = self.const_int(e)
                        if v is None:
                            self.err(e.pos, "CASE label must be an integer constant")
                            continue
                        if isinstance(b, T.Elementary) and not (b.lo <= v <= b.hi):
                            self.err(e.pos, f"CASE label {v} is out of range for {b.name}")
                        values.append(v)
                if len(values) == (2 if lab.hi is not None else 1):
                    lo, hi = values[0], values[-1]
                    for (a, z, p) in seen:
                        if lo <= z and a <= hi:
                            self.err(lab.pos, "duplicate CASE label", f"already covered at {p}")
                            break
                    seen.append((lo, hi, lab.pos))
            self.stmts(body)
        if s.orelse is not None:
            self.stmts(s.orelse)

    def for_stmt(self, s: A.For) -> None:
        vt = self.expr(s.var, self.scope, None)
        sym = s.var.sym
        if isinstance(sym, VarSym):
            if not T.is_elem(vt, "int", "uint"):
                self.err(s.var.pos, f"FOR control variable must be an integer, not {vt}")
            if sym.constant:
                self.err(s.var.pos, f"FOR control variable '{sym.text}' is CONSTANT")
        for e in (s.start, s.end, s.step):
            if e is None:
                continue
            et = self.expr(e, self.scope, vt if not isinstance(vt, T.ErrorType) else None)
            self.assign_compat(e, et, vt, e.pos, "FOR bound")
        if s.step is not None and self.const_int(s.step) == 0:
            self.err(s.step.pos, "FOR step BY 0 never ends")
        self.loop.loop_depth += 1
        if isinstance(sym, VarSym):
            self.loop.for_vars.append(sym)
        self.stmts(s.body)
        if isinstance(sym, VarSym):
            self.loop.for_vars.pop()
        self.loop.loop_depth -= 1

    def call_stmt(self, s: A.CallStmt) -> None:
        c = s.call
        sym = self.scope.lookup(c.func) if self.scope else None
        if sym is None and c.func in self.global_scope:
            sym = self.global_scope[c.func]
        if sym is not None and isinstance(T.resolve_base(sym.type), T.PouType):
            self.fb_call(c, sym)
            return
        if sym is not None and not isinstance(sym.type, T.ErrorType):
            self.err(c.pos, f"'{c.text}' is a variable of type {sym.type}, not a function block instance")
            return
        if sym is not None:
            return
        # a function call used as a statement
        self.port(c.pos, "a FUNCTION call is not a statement in MATIEC",
                  "use the result: `ok := F(...);`", code="portability.call-statement")
        self.expr(c, self.scope, None)

    # -------------------------------------------------------------- FB calls --
    def fb_call(self, c: A.Call, sym: VarSym) -> None:
        ft = T.resolve_base(sym.type)
        c.target = sym
        c.ty = None
        if ft.scope is not None:
            self.bind_args(c, ft.scope, ft.name, sym.text, is_fb=True)

    def is_lvalue(self, e: A.Expr) -> bool:
        if isinstance(e, A.Name):
            return isinstance(e.sym, VarSym)
        if isinstance(e, (A.Member, A.Index)):
            return self.is_lvalue(e.base)
        return isinstance(e, A.Direct)

    # ============================================================ expressions ==
    def expr(self, e: A.Expr, scope: Scope | None, expected: T.Type | None, lvalue: bool = False,
             for_init: bool = False) -> T.Type:
        t = self._expr(e, scope, expected, lvalue)
        e.ty = t
        if expected is not None and isinstance(t, T.LiteralType):
            self.fix_literal(e, expected)
        return e.ty

    def fix_literal(self, e: A.Expr, target: T.Type) -> None:
        """Give an untyped literal (sub)expression the concrete type the context needs."""
        b = T.resolve_base(target)
        if not isinstance(b, T.Elementary) or not isinstance(e.ty, T.LiteralType):
            return
        lit = e.ty
        if lit.cat == "int" and b.cat in ("int", "uint", "bit"):
            v = self.const_int(e)
            if v is not None and not (b.lo <= v <= b.hi):
                self.err(e.pos, f"literal {v} is out of range for {b.name} ({b.lo}..{b.hi})")
            self.set_type(e, b)
        elif lit.cat == "real" and b.cat == "real":
            self.set_type(e, b)
        elif lit.cat == "int" and b.cat == "real":
            self.set_type(e, b)   # an integer literal as a REAL: allowed, value converted
        elif lit.cat == "int" and b.cat == "bool":
            v = self.const_int(e)
            if v in (0, 1):
                self.set_type(e, b)

    def set_type(self, e: A.Expr, t: T.Type) -> None:
        if isinstance(e.ty, T.LiteralType) or e.ty is None:
            e.ty = t
            if isinstance(e, A.Binary):
                self.set_type(e.left, t)
                self.set_type(e.right, t)
            elif isinstance(e, A.Unary):
                self.set_type(e.operand, t)

    def _expr(self, e: A.Expr, scope: Scope | None, expected: T.Type | None, lvalue: bool) -> T.Type:
        if isinstance(e, A.IntLit):
            return self.int_lit(e)
        if isinstance(e, A.RealLit):
            if e.prefix:
                t = T.ELEMENTARY.get(e.prefix)
                if t is None or not t.is_real:
                    self.err(e.pos, f"{e.prefix}# cannot prefix a real literal")
                    return T.ERROR
                return t
            return T.ANY_REAL_LIT
        if isinstance(e, A.BoolLit):
            if e.prefix and e.prefix != "BOOL":
                self.err(e.pos, f"{e.prefix}#{'TRUE' if e.value else 'FALSE'} is not a valid literal")
            return T.BOOL
        if isinstance(e, A.StrLit):
            if e.prefix and e.prefix not in ("STRING",):
                self.err(e.pos, f"{e.prefix}# cannot prefix a string literal")
            n = len(e.value.encode("latin-1", "replace"))
            if n > 126:
                self.err(e.pos, f"string literal of {n} characters is longer than 126")
            elif n == 126:
                self.port(e.pos, "a string literal of 126 characters breaks OpenPLC's C build (125 at most)",
                          code="portability.string-literal")
            return T.STRING
        if isinstance(e, A.TimeLit):
            if e.kind not in TIME_KIND_TYPE:
                self.err(e.pos, f"{e.kind} literals are not supported by MATIEC")
                return T.ERROR
            v = decode(e.kind, e.text)
            if v is None:
                self.err(e.pos, f"invalid {e.kind} literal '{e.text}'",
                         {"TIME": "e.g. T#1s500ms, T#2.5s, T#-5s", "TOD": "e.g. TOD#12:30:00",
                          "DATE": "e.g. D#2024-01-31", "DT": "e.g. DT#2024-01-31-12:30:00"}[e.kind])
                return T.ERROR
            e.value = v
            low = e.text.lower()
            if e.kind == "TIME" and ("us" in low or "ns" in low):
                self.port(e.pos, "'us'/'ns' units in TIME literals are rejected by OpenPLC's MATIEC",
                          "write fractions of ms, e.g. T#1.5ms", code="portability.time-unit")
            return TIME_KIND_TYPE[e.kind]
        if isinstance(e, A.EnumLit):
            return self.enum_lit(e)
        if isinstance(e, A.Name):
            return self.name(e, scope, expected)
        if isinstance(e, A.Member):
            return self.member(e, scope)
        if isinstance(e, A.Index):
            return self.index(e, scope)
        if isinstance(e, A.BitAccess):
            self.port(e.pos, "bit access (w.3) is not accepted by OpenPLC's MATIEC", "use SHR/AND",
                      code="portability.bit-access")
            bt = self.expr(e.base, scope, None)
            b = T.resolve_base(bt)
            if not (isinstance(b, T.Elementary) and b.cat in ("bit", "int", "uint") and b.bits > 1):
                if not isinstance(b, T.ErrorType):
                    self.err(e.pos, f"bit access needs a bit-string or integer variable, not {bt}")
                return T.ERROR
            if not (0 <= e.bit < b.bits):
                self.err(e.pos, f"bit {e.bit} does not exist in {b.name} (0..{b.bits - 1})")
            return T.BOOL
        if isinstance(e, A.Direct):
            return self.direct(e)
        if isinstance(e, A.Deref):
            self.err(e.pos, "pointer dereference '^' is not supported")
            return T.ERROR
        if isinstance(e, A.Unary):
            return self.unary(e, scope, expected)
        if isinstance(e, A.Binary):
            return self.binary(e, scope, expected)
        if isinstance(e, A.Call):
            return self.call_expr(e, scope, expected)
        raise InternalError(e.pos, f"semantic analysis does not handle the expression {type(e).__name__}")

    def int_lit(self, e: A.IntLit) -> T.Type:
        if e.prefix is None:
            return T.ANY_INT_LIT
        t = T.ELEMENTARY.get(e.prefix)
        if t is None:
            if e.prefix in self.type_decls:
                tt = self.named_type(e.prefix, e.pos)
                b = T.resolve_base(tt)
                if isinstance(b, T.Elementary) and b.is_int:
                    t = b
            if t is None:
                self.err(e.pos, f"'{e.prefix}#' cannot prefix an integer literal")
                return T.ERROR
        if t.cat == "real":
            return t
        if t.cat == "bool":
            if e.value not in (0, 1):
                self.err(e.pos, f"BOOL#{e.value} is not a BOOL value")
            return T.BOOL
        if t.cat not in ("int", "uint", "bit"):
            self.err(e.pos, f"'{e.prefix}#' cannot prefix an integer literal")
            return T.ERROR
        if not (t.lo <= e.value <= t.hi):
            self.err(e.pos, f"literal {e.value} is out of range for {t.name} ({t.lo}..{t.hi})")
        return t

    def enum_lit(self, e: A.EnumLit) -> T.Type:
        t = self.named_type(e.type_name, e.pos) if e.type_name in self.type_decls else None
        if t is None:
            self.err(e.pos, f"unknown type '{e.type_name}' in '{e.type_name}#{e.value}'")
            return T.ERROR
        if not isinstance(t, T.EnumType):
            self.err(e.pos, f"'{e.type_name}' is not an enumeration")
            return T.ERROR
        if e.value not in t.values:
            self.err(e.pos, f"'{e.value}' is not a value of {t.name}",
                     f"values: {', '.join(t.values)}")
            return T.ERROR
        e.sym = (t, e.value)
        return t

    def name(self, e: A.Name, scope: Scope | None, expected: T.Type | None) -> T.Type:
        sym = scope.lookup(e.name) if scope else None
        if sym is None and self.func is not None and scope is self.func.scope and e.name == self.func.name:
            e.sym = self.func
            return self.func.ret
        if sym is None and e.name == "CURRENT_TIME" and self.in_builtin():
            e.sym = "CURRENT_TIME"
            return T.TIME
        if sym is None and e.name in ("EN", "ENO") and self.current_pou is not None:
            e.sym = e.name          # the POU's implicit EN input / ENO output
            return T.BOOL
        if sym is not None:
            e.sym = sym
            return sym.type
        enums = self.prog.enum_values.get(e.name)
        if enums:
            exp = T.resolve_base(expected) if expected is not None else None
            if len(enums) == 1:
                et = enums[0]
            elif isinstance(exp, T.EnumType) and exp in enums:
                et = exp
                self.port(e.pos, f"'{e.text}' is a value of several enumerations ({', '.join(x.name for x in enums)}); "
                          "MATIEC needs it qualified", f"write {et.name}#{e.text}", code="portability.enum-qualify")
            else:
                self.err(e.pos, f"enumeration value '{e.text}' is ambiguous ({', '.join(x.name for x in enums)})",
                         f"qualify it: {enums[0].name}#{e.text}")
                return T.ERROR
            e.sym = (et, e.name)
            return et
        if e.name in self.pou_decls:
            self.err(e.pos, f"'{e.text}' is a POU, not a variable")
            return T.ERROR
        cands = list(scope.vars) if scope else []
        self.err(e.pos, f"undeclared variable '{e.text}'", self.suggest(e.name, cands))
        return T.ERROR

    def member(self, e: A.Member, scope: Scope | None) -> T.Type:
        bt = self.expr(e.base, scope, None)
        b = T.resolve_base(bt)
        if isinstance(b, T.ErrorType):
            return T.ERROR
        if isinstance(b, T.StructType):
            m = b.members.get(e.name)
            if m is None:
                self.err(e.pos, f"'{b.name}' has no member '{e.text}'", self.suggest(e.name, b.members))
                return T.ERROR
            return m.type
        if isinstance(b, T.PouType):
            v = b.scope.lookup(e.name) if b.scope else None
            if e.name in ("ENO", "EN") and v is None:
                return T.BOOL
            if v is None:
                self.err(e.pos, f"{b.name} has no member '{e.text}'", self.suggest(e.name, b.scope.vars if b.scope else []))
                return T.ERROR
            if v.section in ("VAR", "VAR_TEMP", "VAR_EXTERNAL") and not self.in_builtin():
                self.err(e.pos, f"'{e.text}' is internal to {b.name}; only inputs and outputs can be read from outside")
                return v.type
            e.sym = v
            return v.type
        self.err(e.pos, f"{bt} has no members ('.{e.text}')")
        return T.ERROR

    def index(self, e: A.Index, scope: Scope | None) -> T.Type:
        bt = self.expr(e.base, scope, None)
        b = T.resolve_base(bt)
        for i in e.indices:
            it = self.expr(i, scope, T.DINT if isinstance(T.resolve_base(self.peek_type(i, scope)), T.LiteralType) else None)
            if not isinstance(it, T.ErrorType) and not T.is_elem(it, "int", "uint"):
                self.err(i.pos, f"array index must be an integer, not {it}")
        if isinstance(b, T.ErrorType):
            return T.ERROR
        if not isinstance(b, T.ArrayType):
            self.err(e.pos, f"{bt} is not an array")
            return T.ERROR
        t: T.Type = b
        idx = list(e.indices)
        while idx:
            tb = T.resolve_base(t)
            if not isinstance(tb, T.ArrayType):
                self.err(idx[0].pos, "too many indices for the array")
                return T.ERROR
            n = min(len(idx), len(tb.dims))
            if len(idx) < len(tb.dims):
                self.err(e.pos, f"array needs {len(tb.dims)} indices, got {len(idx)}")
                return T.ERROR
            for k in range(n):
                v = self.const_int(idx[k])
                lo, hi = tb.dims[k]
                if v is not None and not (lo <= v <= hi):
                    self.err(idx[k].pos, f"index {v} is out of bounds {lo}..{hi}")
            idx = idx[n:]
            t = tb.elem
        return t

    def peek_type(self, e: A.Expr, scope) -> T.Type:
        if isinstance(e, A.IntLit) and e.prefix is None:
            return T.ANY_INT_LIT
        return T.ERROR

    def direct(self, e: A.Direct) -> T.Type:
        self.err(e.pos, f"a direct address in code ({e.text}) is not supported (MATIEC rejects it too)",
                 f"declare a located variable: name AT {e.text} : type;", code="direct-in-code")
        return T.ERROR

    def unary(self, e: A.Unary, scope, expected) -> T.Type:
        t = self.expr(e.operand, scope, expected if e.op != "NOT" else None)
        b = T.resolve_base(t)
        if isinstance(b, T.ErrorType):
            return T.ERROR
        if e.op == "NOT":
            if isinstance(b, T.LiteralType):
                if expected is not None and T.is_elem(expected, "bit"):
                    self.fix_literal(e.operand, expected)
                    return e.operand.ty
                self.err(e.pos, "NOT needs a BOOL or bit-string operand; give the literal a type (WORD#...)")
                return T.ERROR
            if not (isinstance(b, T.Elementary) and b.is_bit):
                self.err(e.pos, f"NOT needs a BOOL or bit-string operand, not {t}")
                return T.ERROR
            return b
        if isinstance(b, T.LiteralType):
            return b
        if not (isinstance(b, T.Elementary) and (b.is_num or b.cat == "time")):
            self.err(e.pos, f"unary '{e.op}' needs a number, not {t}")
            return T.ERROR
        if e.op == "-" and b.cat == "uint":
            self.err(e.pos, f"unary '-' on unsigned {b.name}")
        return b

    ARITH = ("+", "-", "*", "/", "MOD", "**")
    COMPARE = ("=", "<>", "<", ">", "<=", ">=")
    LOGIC = ("AND", "OR", "XOR")

    def binary(self, e: A.Binary, scope, expected) -> T.Type:
        op = e.op
        sub_exp = expected if op in self.ARITH or op in self.LOGIC else None
        lt = self.expr(e.left, scope, None)
        rt = self.expr(e.right, scope, None)
        lb, rb = T.resolve_base(lt), T.resolve_base(rt)
        if isinstance(lb, T.ErrorType) or isinstance(rb, T.ErrorType):
            return T.ERROR
        if op == "**":
            self.port(e.pos, "the '**' operator is missing in OpenPLC", "use EXPT(a, b)", code="portability.power")
            if not (T.is_elem(lb, "real") or isinstance(lb, T.LiteralType)):
                self.err(e.pos, f"'**' needs a REAL or LREAL base, not {lt}")
                return T.ERROR
            if isinstance(lb, T.LiteralType):
                self.fix_literal(e.left, expected if T.is_elem(expected or T.ERROR, "real") else T.LREAL)
                lb = T.resolve_base(e.left.ty)
            if isinstance(rb, T.LiteralType):
                self.fix_literal(e.right, T.DINT if rb.cat == "int" else lb)
            return lb
        # time arithmetic
        if op in ("+", "-", "*", "/") and (T.is_elem(lb, "time", "date", "tod", "dt") or T.is_elem(rb, "time", "date", "tod", "dt")):
            return self.time_arith(e, lb, rb)
        # settle literals against the other side
        if isinstance(lb, T.LiteralType) and not isinstance(rb, T.LiteralType):
            self.fix_literal(e.left, rb)
            lb = T.resolve_base(e.left.ty)
        elif isinstance(rb, T.LiteralType) and not isinstance(lb, T.LiteralType):
            self.fix_literal(e.right, lb)
            rb = T.resolve_base(e.right.ty)
        elif isinstance(lb, T.LiteralType) and isinstance(rb, T.LiteralType):
            if op in self.COMPARE:
                lit = T.ANY_REAL_LIT if "real" in (lb.cat, rb.cat) else T.ANY_INT_LIT
                tgt = T.LREAL if lit.cat == "real" else T.LINT
                self.fix_literal(e.left, tgt)
                self.fix_literal(e.right, tgt)
                return T.BOOL
            if op in self.LOGIC:
                if expected is not None and T.is_elem(expected, "bit", "bool"):
                    self.fix_literal(e.left, expected)
                    self.fix_literal(e.right, expected)
                    return T.resolve_base(expected)
                self.err(e.pos, f"{op} of two untyped literals: give one a type (WORD#...)")
                return T.ERROR
            if "real" in (lb.cat, rb.cat):
                return T.ANY_REAL_LIT
            if op == "/" and self.const_int(e.right) == 0:
                self.err(e.right.pos, "division by zero")
            return T.ANY_INT_LIT
        if isinstance(lb, T.LiteralType) or isinstance(rb, T.LiteralType):
            # fix_literal could not give the literal the other side's type (2.5 + i, 1.0 MOD d)
            lit, other = (lb, rt) if isinstance(lb, T.LiteralType) else (rb, lt)
            self.err(e.pos, f"'{op}' of {'a REAL' if lit.cat == 'real' else 'an integer'} literal and {other}: "
                     f"the literal is not a {other}", self.conv_hint(lt, rt) if lit.cat != "real" else None)
            return T.ERROR
        if op in self.COMPARE:
            if not self.same_for_op(lb, rb):
                self.err(e.pos, f"cannot compare {lt} with {rt}", self.conv_hint(lt, rt))
                return T.ERROR
            if isinstance(lb, (T.StructType, T.ArrayType, T.PouType)):
                self.err(e.pos, f"cannot compare values of type {lt}")
                return T.ERROR
            if isinstance(lb, T.EnumType) and op not in ("=", "<>"):
                self.port(e.pos, f"'{op}' on enumeration values is rejected by MATIEC", "compare with = or <>",
                          code="portability.enum-order")
            return T.BOOL
        if op in self.LOGIC:
            if not (isinstance(lb, T.Elementary) and lb.is_bit):
                self.err(e.pos, f"{op} needs BOOL or bit-string operands, not {lt}",
                         "integers are not bit strings in IEC: convert with INT_TO_WORD" if T.is_elem(lb, "int", "uint") else None)
                return T.ERROR
            if not self.same_for_op(lb, rb):
                self.err(e.pos, f"{op} of {lt} and {rt}: both sides must have the same type", self.conv_hint(lt, rt))
                return T.ERROR
            return lb
        # arithmetic
        if isinstance(lb, T.Elementary) and lb.cat in ("bit", "bool"):
            self.err(e.pos, f"arithmetic '{op}' on {lt} (a bit string) is not allowed",
                     f"convert first, e.g. {lb.name}_TO_UINT" if lb.cat == "bit" else None)
            return T.ERROR
        if not (isinstance(lb, T.Elementary) and lb.is_num):
            self.err(e.pos, f"arithmetic '{op}' needs numbers, not {lt}")
            return T.ERROR
        if not self.same_for_op(lb, rb):
            self.err(e.pos, f"'{op}' of {lt} and {rt}: both sides must have the same type (no implicit conversion)",
                     self.conv_hint(lt, rt))
            return T.ERROR
        if op == "MOD" and lb.is_real:
            self.err(e.pos, "MOD needs integers")
            return T.ERROR
        if op in ("/", "MOD") and self.const_int(e.right) == 0 and lb.is_int:
            if op == "/":
                self.err(e.right.pos, "integer division by zero")
        return lb

    def same_for_op(self, a: T.Type, b: T.Type) -> bool:
        return T.same_type(a, b)

    def conv_hint(self, a: T.Type, b: T.Type) -> str | None:
        a, b = T.resolve_base(a), T.resolve_base(b)
        if isinstance(a, T.Elementary) and isinstance(b, T.Elementary) and a.name != b.name:
            small, big = (a, b) if a.size <= b.size else (b, a)
            return f"convert explicitly, e.g. {small.name}_TO_{big.name}(...)"
        return None

    def time_arith(self, e: A.Binary, lb: T.Type, rb: T.Type) -> T.Type:
        op = e.op
        lc = lb.cat if isinstance(lb, T.Elementary) else ("lit" + lb.cat if isinstance(lb, T.LiteralType) else "?")
        rc = rb.cat if isinstance(rb, T.Elementary) else ("lit" + rb.cat if isinstance(rb, T.LiteralType) else "?")
        table = {
            ("+", "time", "time"): T.TIME, ("-", "time", "time"): T.TIME,
            ("+", "tod", "time"): T.TOD, ("-", "tod", "time"): T.TOD, ("-", "tod", "tod"): T.TIME,
            ("+", "dt", "time"): T.DT, ("-", "dt", "time"): T.DT, ("-", "dt", "dt"): T.TIME,
            ("-", "date", "date"): T.TIME,
        }
        if (op, lc, rc) in table:
            return table[(op, lc, rc)]
        if op in ("*", "/") and lc == "time" and (rc in ("int", "uint", "real", "litint", "litreal")):
            if rc.startswith("lit"):
                self.fix_literal(e.right, T.LREAL if rc == "litreal" else T.DINT)
            if op == "/" and self.const_value(e.right) == 0:
                self.err(e.right.pos, "division of a TIME by zero")
            return T.TIME
        if op == "*" and rc == "time" and lc in ("int", "uint", "real", "litint", "litreal"):
            if lc.startswith("lit"):
                self.fix_literal(e.left, T.LREAL if lc == "litreal" else T.DINT)
            return T.TIME
        self.err(e.pos, f"'{op}' is not defined for {lb} and {rb}")
        return T.ERROR

    # ------------------------------------------------------------------ calls --
    def call_expr(self, c: A.Call, scope, expected) -> T.Type:
        sym = scope.lookup(c.func) if scope else None
        if sym is not None:
            if isinstance(T.resolve_base(sym.type), T.PouType):
                self.err(c.pos, f"'{c.text}' is a function block instance: call it as a statement, then read its outputs",
                         f"{c.text}(...); x := {c.text}.Q;")
            else:
                self.err(c.pos, f"'{c.text}' is a variable, not a function")
            return T.ERROR
        if not c.args:
            self.port(c.pos, "a call with no arguments F() is not accepted by MATIEC",
                      code="portability.empty-call")
        fs = self.prog.funcs.get(c.func)
        if fs is not None:
            c.target = fs
            self.user_call(c, fs, scope)
            self.mark_assert_site(c, fs)
            return fs.ret
        conv = conversion(c.func)
        if conv is not None:
            return self.conversion_call(c, conv, scope)
        std = STD_FUNCS.get(c.func)
        if std is not None:
            c.target = std
            return std.check(self, c, scope, expected)
        if c.func in self.prog.pous:
            self.err(c.pos, f"'{c.text}' is a {self.prog.pous[c.func].kind}: declare an instance and call that")
            return T.ERROR
        self.err(c.pos, f"unknown function '{c.text}'",
                 self.suggest(c.func, list(self.prog.funcs) + list(STD_FUNCS)))
        return T.ERROR

    def mark_assert_site(self, c: A.Call, fs: FuncSym) -> None:
        if self.test_build and fs.builtin and (fs.name.startswith("ASSERT") or fs.name == "FAIL"):
            c.site = self.prog.site(c.pos, self.current_pou.text if self.current_pou else "")

    def user_call(self, c: A.Call, fs: FuncSym, scope) -> None:
        self.bind_args(c, fs.scope, fs.text, fs.text, is_fb=False)

    def bind_args(self, c: A.Call, callee: Scope, callee_name: str, call_name: str, is_fb: bool) -> None:
        """Match a call's arguments to the callee's parameters and check each (FB instances and FUNCTIONs)."""
        params = callee.params()
        positional = [a for a in c.args if a.name is None]
        formal = [a for a in c.args if a.name is not None]
        if positional and formal:
            self.err(c.pos, f"call of {c.text} mixes positional and formal (name :=) arguments")
            if is_fb:
                return
        if positional:
            ins = [p for p in params if p.section in ("VAR_INPUT", "VAR_IN_OUT")]
            if len(positional) > len(ins):
                self.err(positional[len(ins)].pos, f"too many arguments for {callee_name} (it has {len(ins)} inputs)")
            for a, p in zip(positional, ins):
                a.name = p.name
            if not is_fb and len(positional) < len(ins) and not formal:
                missing = [p.text for p in ins[len(positional):]]
                self.err(c.pos, f"call of {callee_name} is missing {', '.join(missing)}",
                         "a positional call must give every input")
        seen = set()
        for a in c.args:
            if a.name is None:          # a positional argument past the inputs: reported above
                if not is_fb and a.value is not None:
                    self.expr(a.value, self.scope, None)
                continue
            if a.name in seen:
                self.err(a.pos, f"parameter '{a.text or a.name}' given twice")
                continue
            seen.add(a.name)
            if a.name in ("EN", "ENO"):
                self.en_eno_arg(a)
                continue
            p = callee.lookup(a.name)
            if p is None or p.section not in ("VAR_INPUT", "VAR_OUTPUT", "VAR_IN_OUT"):
                self.err(a.pos, f"{callee_name} has no parameter '{a.text or a.name}'",
                         self.suggest(a.name, [q.name for q in params]))
                continue
            a.param = p
            if p.section == "VAR_OUTPUT":
                if not a.output:
                    self.err(a.pos, f"'{p.text}' is an output: write `{p.text} => variable`")
                elif a.value is not None:
                    tt = self.lvalue(a.value, "write an output into")
                    self.assign_compat(a.value, p.type, tt, a.pos, f"output {p.text}")
                continue
            if a.output:
                self.err(a.pos, f"'{p.text}' is an input: write `{p.text} := value`")
                continue
            if a.value is None:
                if p.section == "VAR_IN_OUT" and not is_fb:
                    self.err(a.pos, f"VAR_IN_OUT '{p.text}' must be connected with :=")
                continue
            if p.section == "VAR_IN_OUT":
                at = self.lvalue(a.value, "pass as VAR_IN_OUT")
                if not self.is_lvalue(a.value):
                    self.err(a.pos, f"VAR_IN_OUT '{p.text}' needs a variable, not an expression")
                elif not T.same_type(at, p.type) and not isinstance(at, T.ErrorType):
                    self.err(a.pos, f"VAR_IN_OUT '{p.text}' is {p.type}, the argument is {at}")
                elif not is_fb and isinstance(a.value, A.Index):
                    self.port(a.pos, "an array element as a FUNCTION's VAR_IN_OUT breaks OpenPLC's C build",
                              "copy it to a variable and back", code="portability.inout-element")
            else:
                at = self.expr(a.value, self.scope, p.type)
                self.assign_compat(a.value, at, p.type, a.pos, f"input {p.text}")
        for p in params:
            if p.section == "VAR_IN_OUT" and p.name not in seen:
                self.err(c.pos, f"call of {call_name} must connect VAR_IN_OUT '{p.text}'")

    def en_eno_arg(self, a: A.Arg) -> None:
        """EN := condition and ENO => variable, accepted by every call."""
        if a.name == "EN" and not a.output:
            if a.value is None:
                self.err(a.pos, "EN := needs a value")
                return
            self.expr(a.value, self.scope, T.BOOL)
            self.assign_compat(a.value, a.value.ty, T.BOOL, a.pos, "EN")
        elif a.name == "ENO" and a.output:
            if a.value is not None:
                tt = self.lvalue(a.value, "write ENO into")
                self.assign_compat(a.value, T.BOOL, tt, a.pos, "ENO")
        else:
            self.err(a.pos, f"{a.name} must be passed with {'=>' if a.name == 'ENO' else ':='}")

    def conversion_call(self, c: A.Call, conv, scope) -> T.Type:
        src, dst, generic = conv
        c.target = ("CONV", src, dst)
        for a in c.args:
            if a.name in ("EN", "ENO"):
                self.en_eno_arg(a)
        c.args = [a for a in c.args if a.name not in ("EN", "ENO")] + \
            [a for a in c.args if a.name in ("EN", "ENO")]
        if len([a for a in c.args if a.name not in ("EN", "ENO")]) != 1 or c.args[0].output:
            self.err(c.pos, f"{c.text} takes exactly one input")
            for a in c.args:
                if a.value is not None and not a.output:
                    self.expr(a.value, scope, None)
            return dst
        a = c.args[0]
        if a.name not in (None, "IN"):
            self.err(a.pos, f"{c.text} has no parameter '{a.text}'", "its input is IN")
        if generic:
            self.port(c.pos, f"generic conversion {c.text} is IEC edition 3; OpenPLC needs <TYPE>_TO_{dst.name}",
                      code="portability.generic-conversion")
        at = self.expr(a.value, scope, src)
        ab = T.resolve_base(at)
        if isinstance(ab, T.ErrorType):
            return dst
        if generic:
            if isinstance(ab, T.LiteralType):
                self.fix_literal(a.value, T.LINT if ab.cat == "int" else T.LREAL)
                ab = T.resolve_base(a.value.ty)
            c.target = ("CONV", ab, dst)
        elif not T.same_type(ab, src) and not isinstance(ab, T.LiteralType):
            self.err(a.pos, f"{c.text} needs a {src.name} input, not {at}",
                     f"use {T.resolve_base(at).name}_TO_{dst.name}" if isinstance(ab, T.Elementary) else None)
        if c.func in ("TIME_TO_DINT", "DINT_TO_TIME", "TIME_TO_INT", "INT_TO_TIME", "TIME_TO_UDINT",
                      "UDINT_TO_TIME", "TIME_TO_LINT", "LINT_TO_TIME", "TIME_TO_ULINT", "ULINT_TO_TIME",
                      "TIME_TO_UINT", "UINT_TO_TIME", "TIME_TO_SINT", "SINT_TO_TIME", "TIME_TO_USINT", "USINT_TO_TIME"):
            self.port(c.pos, f"{c.text} counts seconds in OpenPLC's MATIEC (not milliseconds)",
                      "keep durations as TIME and compare TIME values", code="portability.time-conversion")
        return dst

    # ------------------------------------------------------------ compatibility --
    def assign_compat(self, e: A.Expr | None, src: T.Type, dst: T.Type, pos: Pos, what: str) -> bool:
        if src is None or dst is None:
            return True
        sb, db = T.resolve_base(src), T.resolve_base(dst)
        if isinstance(sb, T.ErrorType) or isinstance(db, T.ErrorType):
            return True
        if isinstance(sb, T.LiteralType):
            if e is not None:
                self.fix_literal(e, dst)
                if isinstance(e.ty, T.LiteralType):
                    if sb.cat == "real" and T.is_elem(db, "int", "uint", "bit"):
                        self.err(pos, f"{what}: a REAL literal cannot go into {dst}")
                    elif T.is_elem(db, "bool"):
                        self.err(pos, f"{what}: an integer literal cannot go into BOOL", "use TRUE or FALSE")
                    else:
                        self.err(pos, f"{what}: a number cannot go into {dst}")
                    return False
                self.check_subrange(e, dst)
            return True
        if T.same_type(sb, db):
            if isinstance(dst, T.SubrangeType) and e is not None:
                self.check_subrange(e, dst)
            if isinstance(sb, T.StructType) and sb is not db:
                self.err(pos, f"{what}: {src} is not {dst}")
                return False
            return True
        if isinstance(sb, T.Elementary) and isinstance(db, T.Elementary):
            hint = f"convert explicitly: {sb.name}_TO_{db.name}(...)"
            if sb.is_int and db.is_int and sb.size < db.size:
                self.err(pos, f"{what}: implicit conversion from {sb.name} to {db.name} (MATIEC does not widen implicitly)",
                         hint, code="type-widening")
            else:
                self.err(pos, f"{what}: type mismatch, {src} cannot go into {dst}", hint, code="type-mismatch")
            return False
        self.err(pos, f"{what}: type mismatch, {src} cannot go into {dst}", code="type-mismatch")
        return False

    def check_subrange(self, e: A.Expr, dst: T.Type) -> None:
        if isinstance(dst, T.SubrangeType):
            v = self.const_int(e)
            if v is not None and not (dst.lo <= v <= dst.hi):
                self.err(e.pos, f"value {v} is outside the subrange {dst.lo}..{dst.hi} of {dst.name}")


def analyze(files: list[A.SourceFile], diags: Diagnostics, builtin_files: set[str] | None = None,
            test_build: bool = False) -> Program:
    a = Analyzer(files, diags, builtin_files, test_build)
    a.func = None
    a.scope = None
    a.loop = LoopCtx()
    return a.run()
