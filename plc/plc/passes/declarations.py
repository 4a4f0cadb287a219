"""Pass 1, declarations: every TYPE, POU and CONFIGURATION name of the build, duplicates and reserved names
reported; POU types are known before any type is resolved.
"""
from __future__ import annotations

from .. import ast as A
from .. import types as T
from ..diagnostics import Pos
from ..stdfuncs import STD_FUNCS, conversion
from .context import PassBase


class DeclarationPass(PassBase):
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
