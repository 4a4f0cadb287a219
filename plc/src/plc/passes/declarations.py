"""Pass 1, declarations: every TYPE, POU and CONFIGURATION name of the build, duplicates and reserved names
reported; POU types are known before any type is resolved.
"""
from __future__ import annotations

from .. import ast as A
from .. import types as T
from ..diagnostics import Pos
from ..stdfuncs import STD_FUNCS, conversion
from .context import Pass


class DeclarationPass(Pass):
    pass_name = "declarations"

    def __init__(self, st) -> None:
        super().__init__(st)
        self.declared: dict[str, Pos] = {}       # name -> where it was first declared

    def run(self) -> None:
        for f in self.st.files:
            for item in f.items:
                A.handler(self, "d_", item, "the declarations pass")(item)
        # POU types are known before any type is resolved (FB instances as struct members are errors)
        for name, pou in self.st.pou_decls.items():
            if pou.kind in ("FUNCTION_BLOCK", "PROGRAM"):
                self.st.prog.pous[name] = T.PouType(name, pou, pou.kind,
                                                    builtin=pou.pos.file in self.st.prog.builtin_files)

    def claim(self, name: str, text: str, pos: Pos, what: str) -> bool:
        """Whether `name` is free for a new type, POU or configuration (a clash is reported)."""
        if name in self.declared:
            first = self.declared[name]
            self.err(pos, f"duplicate {what} name '{text}'", f"first declared at {first}")
            return False
        if name in T.ELEMENTARY or name in T.UNSUPPORTED or name in T.GENERIC:
            self.err(pos, f"'{text}' is the name of an elementary type")
            return False
        if name in STD_FUNCS or conversion(name) is not None:
            if pos.file not in self.st.prog.builtin_files:
                self.err(pos, f"'{text}' is the name of a standard function")
                return False
        self.declared[name] = pos
        return True

    def d_TypeBlock(self, item: A.TypeBlock) -> None:
        for td in item.decls:
            if self.claim(td.name, td.text, td.pos, "type"):
                self.st.type_decls[td.name] = td

    def d_Pou(self, item: A.Pou) -> None:
        if self.claim(item.name, item.text, item.pos, "POU"):
            self.st.pou_decls[item.name] = item

    def d_Configuration(self, item: A.Configuration) -> None:
        self.claim(item.name, item.text, item.pos, "CONFIGURATION")

    def d_VarBlock(self, item: A.VarBlock) -> None:
        # VAR_GLOBAL outside a configuration (extension): treat as globals of every configuration
        for vd in item.decls:
            self.st.global_scope.setdefault(vd.name, None)  # filled in configuration()
