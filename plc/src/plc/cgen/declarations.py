"""C declarations: POU instance structs, FUNCTION prototypes, globals, assertion site table.
"""
from __future__ import annotations

from .. import types as T
from ..symbols import FuncSym
from .base import STATIC, GenBase, cid


class DeclarationGen(GenBase):
    def pou_struct(self, pt: T.PouType) -> None:
        w = self.w
        w(f"struct P_{pt.name} {{")
        w("    uint8_t EN;")
        w("    uint8_t ENO;")
        for v in pt.scope.vars.values():
            if v.section == "VAR_EXTERNAL":
                continue
            if v.location is not None:
                w(f"    {self.ctype(v.type)} *{cid(v.name)};")
                w(f"    {self.ctype(v.type)} {cid(v.name)}__L;")
            else:
                w(f"    {self.ctype(v.type)} {cid(v.name)};")
        w("};")

    def func_proto(self, fs: FuncSym) -> str:
        params = []
        for v in fs.scope.params():
            ct = self.ctype(v.type)
            if v.section == "VAR_INPUT":
                params.append(f"{ct} {cid(v.name)}")
            else:
                params.append(f"{ct} *{cid(v.name)}")
        params.append("uint8_t *ENO__")        # the implicit ENO output, which the body may clear
        return f"{STATIC} {self.ctype(fs.ret)} U_{fs.name}({', '.join(params)})"

    # --------------------------------------------------------------- globals --
    def globals_decl(self) -> None:
        if self.cfg is None:
            # no CONFIGURATION (a library build): VAR_EXTERNALs have nothing to bind to, so each
            # name gets private storage and the blocks still compile and run (in tests, say)
            seen = set()
            for pt in self.p.pous.values():
                for v in (pt.scope.vars.values() if pt.scope is not None else []):
                    if v.section == "VAR_EXTERNAL" and v.global_sym is None and v.name not in seen:
                        seen.add(v.name)
                        self.w(f"{STATIC} {self.ctype(v.type)} G_{cid(v.name)};")
            return
        for g in self.cfg.globals.values():
            ct = self.ctype(g.type)
            if g.location is not None:
                self.w(f"{STATIC} {ct} *G_{cid(g.name)};")
                self.w(f"{STATIC} {ct} G_{cid(g.name)}__L;")
            else:
                self.w(f"{STATIC} {ct} G_{cid(g.name)};")
        for inst in self.cfg.instances:
            inst.cname = f"I_{inst.resource}_{inst.name}" if inst.resource else f"I_{inst.name}"
            self.w(f"{STATIC} P_{inst.type.name} {inst.cname};")

    def site_table(self) -> None:
        # sites are numbered during generation; emit a forward declaration now, the table at the end
        self.w("const plc_site_t plc_sites[];")
        self.w("const uint32_t plc_n_sites;")

    def site(self, pos) -> int:
        return self.p.site(pos, self.pou.text if self.pou else "")
