"""Pass 3, scopes: each POU's variable scope, its declarations, located variables and initial values checked.
"""
from __future__ import annotations

from .. import ast as A
from .. import types as T
from ..symbols import EnumValueSym, FuncSym, Scope, VarSym
from .context import Pass, LOCATION_SIZES, LOCATED_OK


class ScopePass(Pass):
    pass_name = "scopes"

    def __init__(self, st) -> None:
        super().__init__(st)
        self.locations: dict[tuple, A.VarDecl] = {}      # (scope, (area, size, parts)) -> first declaration
        self.output_owner: dict[tuple, tuple[str, A.VarDecl, str]] = {}   # %Q address -> first scope

    def run(self) -> None:
        for name, pou in self.st.pou_decls.items():
            self.st.current_pou = pou
            scope = Scope(name, pou.kind)
            self.st.scope = scope
            if pou.kind == "FUNCTION":
                ret = self.type_pass.type_ref(pou.ret) if pou.ret else T.ERROR
                if isinstance(ret, T.PouType):
                    self.err(pou.ret.pos, "a FUNCTION cannot return a function block")
                    ret = T.ERROR
                fs = FuncSym(name, pou.text, pou, ret, scope, builtin=pou.pos.file in self.st.prog.builtin_files)
                self.st.prog.funcs[name] = fs
            else:
                self.st.prog.pous[name].scope = scope
            for block in pou.blocks:
                self.var_block(block, scope, pou)
            self.st.current_pou = None
            self.st.scope = None

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
            self.port(block.pos, "mixed-located")
        for d in block.decls:
            self.declare_var(d, scope, pou, block)

    def declare_var(self, d: A.VarDecl, scope: Scope, pou: A.Pou | None, block: A.VarBlock) -> VarSym | None:
        if d.name in scope.vars:
            first = scope.vars[d.name]
            self.err(d.pos, f"duplicate variable '{d.text}'", f"first declared at {first.pos}")
            return None
        if d.name in ("EN", "ENO"):
            # a VAR_INPUT en could never be passed: fb(en := x) sets the implicit EN (and x FALSE skips the body)
            self.err(d.pos, f"'{d.text}' cannot be declared: EN and ENO are the implicit enable input and output "
                     "of every POU", "rename the variable")
        elif pou is not None and d.name == pou.name and pou.kind == "FUNCTION":
            self.err(d.pos, f"'{d.text}' is the name of the FUNCTION itself (its result)")
            return None
        t = self.type_pass.type_spec(d.spec)
        if isinstance(d.spec, A.SubrangeSpec) and isinstance(t, T.SubrangeType) and d.init is None and t.lo != 0 \
                and d.section not in ("VAR_IN_OUT", "VAR_EXTERNAL"):
            self.port(d.pos, "subrange-default", lo=t.lo)
        if isinstance(t, T.PouType) and d.section == "VAR_GLOBAL":
            self.port(d.pos, "global-fb")
        if isinstance(t, T.PouType):
            if t.kind == "PROGRAM":
                self.err(d.pos, "a PROGRAM cannot be instantiated inside a POU", "instantiate it in a RESOURCE")
                t = T.ERROR
            elif pou is not None and pou.kind == "FUNCTION":
                self.err(d.pos, "a FUNCTION cannot contain function block instances")
                t = T.ERROR
            elif d.section == "VAR_IN_OUT":
                self.port(d.pos, "fb-inout")
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
            init = self.type_pass.alias_init(d.spec)
        sym = VarSym(d.name, d.text, t, d.section, d.pos, d, block.constant, block.retain, d.location, init,
                     owner=pou.name if pou else "")
        if block.constant and d.init is not None and isinstance(d.init, A.Expr):
            sym.const_value = self.const_eval.const_value(d.init)
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
                self.port(init.pos, "struct-array-init")
            count = 0
            elem = b.elem
            for rep, v in init.items:
                n = 1
                if rep is not None:
                    n = self.const_eval.const_int(rep) or 0
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
        saved = self.st.scope
        ty = self.expr_typing.expr(init, saved, t, for_init=True)
        self.call_typing.assign_compat(init, ty, t, init.pos, "initial value")
        if not self.is_constant_expr(init):
            self.err(init.pos, "an initial value must be a constant expression")

    def is_constant_expr(self, e: A.Expr) -> bool:
        if isinstance(e, (A.IntLit, A.RealLit, A.BoolLit, A.StrLit, A.TimeLit, A.EnumLit)):
            return True
        if isinstance(e, A.Name):
            return isinstance(e.sym, EnumValueSym) or (isinstance(e.sym, VarSym) and e.sym.constant)
        if isinstance(e, A.Unary):
            return self.is_constant_expr(e.operand)
        if isinstance(e, A.Binary):
            return self.is_constant_expr(e.left) and self.is_constant_expr(e.right)
        return False
