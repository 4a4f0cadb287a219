"""C declarations: POU instance structs, FUNCTION prototypes, globals, assertion site table.
"""
from __future__ import annotations

from .. import types as T
from ..symbols import FuncSym
from .base import MAIN_UNIT, STATIC, GenBase, cid, unit_id


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
        return f"{self.linkage} {self.ctype(fs.ret)} U_{fs.name}({', '.join(params)})"

    # --------------------------------------------------------------- globals --
    def globals_decl(self) -> None:
        """Every global variable and program instance, one piece each; a split build declares them extern and
        defines them in the main unit."""
        for names, decls in self.global_decls():
            with self.piece(*names):
                for decl in decls:
                    self.w(f"extern {decl}" if self.split else f"{STATIC} {decl}")
            if self.split:
                with self.piece(unit=MAIN_UNIT):
                    for decl in decls:
                        self.w(decl)

    def global_decls(self) -> list[tuple[tuple[str, ...], list[str]]]:
        """(C names, C declarations without storage class) of each global variable and program instance."""
        out = []
        if self.cfg is None:
            # no CONFIGURATION (a library build): VAR_EXTERNALs have nothing to bind to, so each
            # name gets private storage and the blocks still compile and run (in tests, say)
            seen = set()
            for pt in self.p.pous.values():
                for v in (pt.scope.vars.values() if pt.scope is not None else []):
                    if v.section == "VAR_EXTERNAL" and v.global_sym is None and v.name not in seen:
                        seen.add(v.name)
                        out.append(((f"G_{cid(v.name)}",), [f"{self.ctype(v.type)} G_{cid(v.name)};"]))
            return out
        for g in self.cfg.globals.values():
            ct, name = self.ctype(g.type), f"G_{cid(g.name)}"
            if g.location is not None:
                out.append(((name, f"{name}__L"), [f"{ct} *{name};", f"{ct} {name}__L;"]))
            else:
                out.append(((name,), [f"{ct} {name};"]))
        for inst in self.cfg.instances:
            inst.cname = f"I_{inst.resource}_{inst.name}" if inst.resource else f"I_{inst.name}"
            out.append(((inst.cname,), [f"P_{inst.type.name} {inst.cname};"]))
        return out

    def site_table(self) -> None:
        # sites are numbered during generation; emit a forward declaration now, the table at the end (a split
        # build's units have plc_abi.h's extern declaration)
        if self.split:
            return
        self.w("const plc_site_t plc_sites[];")
        self.w("const uint32_t plc_n_sites;")

    def site(self, pos) -> str:
        """The C of a new site at `pos` (an index into plc_sites)."""
        return self.site_ref(self.p.site(pos, self.pou.text if self.pou else ""))

    def site_ref(self, site: int) -> str:
        """The C of site number `site`: the number itself, or in a split build an entry of the unit's own site
        map, so that sites numbered in other units do not change this unit's text."""
        if not self.split:
            return str(site)
        used = self.unit_sites.setdefault(self.unit, [])
        used.append(site)
        return f"{self.site_map_name(self.unit)}[{len(used) - 1}]"

    def site_map_name(self, unit: str) -> str:
        return f"plc_sitemap_{unit_id(unit)}"

    def site_map_decl(self, unit: str) -> str:
        return f"extern const int32_t {self.site_map_name(unit)}[];"

    def emit_site_maps(self) -> None:
        for unit, sites in self.unit_sites.items():
            self.w(f"const int32_t {self.site_map_name(unit)}[] = {{{', '.join(map(str, sites))}}};")
