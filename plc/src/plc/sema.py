"""Semantic analysis: the passes of plc/src/plc/passes over one shared state.

Input: the parsed files.  Output: a `Program` — the same AST with its
annotations filled in (every expression's `ty`, every name's `sym`, every
call's `target`, ...; see ast.py) plus the tables the C generator needs.

Each pass is a class in its own module of plc/src/plc/passes, handed one
explicit state object (passes.context.SemanticState: the files, the
diagnostics, the Program being built, the declarations, the globals); what a
pass needs only for itself it keeps itself.  driver.SEMANTIC_PASSES names the
order; analyze() below runs them:

1. declarations  — every TYPE, POU and CONFIGURATION name (duplicates reported);
2. types         — type declarations resolved (forward references are fine);
3. scopes        — each POU's variable scope, declarations and locations checked;
4. configuration — tasks, program instances, globals, located variables;
5. externals     — every VAR_EXTERNAL bound to its global;
6. bodies        — statements and expressions typed with MATIEC's strictness.

Three helpers answer the passes and have no pass of their own: constants
(compile-time values), expressions and calls (typing).  A pass reaches another
through the named accessors of passes.context.Pass (`self.type_pass`,
`self.expr_typing`, ...).

Every problem becomes a diagnostic; checking goes on with an error type so one
mistake does not cascade.  A node kind a pass does not handle is an
`InternalError` at its position.
"""
from __future__ import annotations

from typing import Callable

from .diagnostics import Diagnostics
from . import ast as A
from .passes.calls import CallTyping
from .passes.configuration import ConfigurationPass
from .passes.constants import ConstantEval
from .passes.context import Pass, Program, SemanticState
from .passes.declarations import DeclarationPass
from .passes.expressions import ExpressionTyping
from .passes.externals import ExternalsPass
from .passes.scopes import ScopePass
from .passes.statements import StatementPass
from .passes.typedecls import TypePass

__all__ = ["PASSES", "HELPERS", "Program", "SemanticState", "analyze"]

# Every pass by the name driver.SEMANTIC_PASSES orders them with.
PASSES: dict[str, type[Pass]] = {p.pass_name: p for p in (DeclarationPass, TypePass, ScopePass, ConfigurationPass,
                                                      ExternalsPass, StatementPass)}
# The helpers the passes ask (constants, expression and call typing): no pass of their own.
HELPERS: dict[str, type[Pass]] = {p.pass_name: p for p in (ConstantEval, ExpressionTyping, CallTyping)}


def analyze(files: list[A.SourceFile], diags: Diagnostics, order: tuple[str, ...],
            builtin_files: set[str] | None = None, test_build: bool = False,
            skip_bodies: Callable[[A.Pou], bool] | None = None) -> Program:
    """Run the passes named in `order` over one shared SemanticState; return the typed Program.  The bodies pass
    leaves out the POUs `skip_bodies` names (their C comes from the build cache: codegen.PieceMemo)."""
    st = SemanticState(files, diags, builtin_files, test_build)
    st.skip_bodies = skip_bodies
    for name, cls in {**HELPERS, **PASSES}.items():
        st.passes[name] = cls(st)
    for name in order:
        st.passes[name].run()
    return st.prog
