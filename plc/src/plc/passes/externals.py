"""Pass 5, externals: every VAR_EXTERNAL bound to the VAR_GLOBAL of the same name (same type; CONSTANT when the
global is).
"""
from __future__ import annotations

from .. import types as T
from .context import Pass


class ExternalsPass(Pass):
    pass_name = "externals"

    def run(self) -> None:
        for pou_name, pou in self.st.pou_decls.items():
            scope = self.st.prog.funcs[pou_name].scope if pou.kind == "FUNCTION" else self.st.prog.pous[pou_name].scope
            for v in scope.vars.values():
                if v.section != "VAR_EXTERNAL":
                    continue
                g = self.st.global_scope.get(v.name)
                if g is None:
                    if self.st.prog.configs:
                        self.err(v.pos, f"VAR_EXTERNAL '{v.text}' has no matching VAR_GLOBAL in the configuration")
                    continue
                if not T.same_type(g.type, v.type) and not isinstance(v.type, T.ErrorType):
                    self.err(v.pos, f"VAR_EXTERNAL '{v.text}' is {v.type} but the VAR_GLOBAL is {g.type}",
                             f"declared at {g.pos}")
                if g.constant and not v.constant:
                    self.err(v.pos, f"VAR_EXTERNAL '{v.text}' must be CONSTANT: the VAR_GLOBAL is CONSTANT")
                v.global_sym = g
