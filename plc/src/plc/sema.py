"""Semantic analysis: the passes of plc/src/plc/passes over one shared state.

Input: the parsed files.  Output: a `Program` — the same AST with its
annotations filled in (every expression's `ty`, every name's `sym`, every
call's `target`, ...; see ast.py) plus the tables the C generator needs.

Each concern is a module of plc/src/plc/passes; `Analyzer` joins them because the
later passes ask the earlier ones (the bodies pass evaluates constants and
resolves types).  driver.SEMANTIC_PASSES runs them, in this order:

1. declarations  — every TYPE, POU and CONFIGURATION name (duplicates reported);
2. types         — type declarations resolved (forward references are fine);
3. scopes        — each POU's variable scope, declarations and locations checked;
4. configuration — tasks, program instances, globals, located variables;
5. externals     — every VAR_EXTERNAL bound to its global;
6. bodies        — statements and expressions typed with MATIEC's strictness.

Every problem becomes a diagnostic; checking goes on with an error type so one
mistake does not cascade.  A node kind a pass does not handle is an
`InternalError` at its position.
"""
from __future__ import annotations

from .passes.calls import CallTyping
from .passes.configuration import ConfigurationPass
from .passes.constants import ConstantEval
from .passes.context import PassBase, Program
from .passes.declarations import DeclarationPass
from .passes.expressions import ExpressionTyping
from .passes.scopes import ScopePass
from .passes.statements import StatementPass
from .passes.typedecls import TypePass

__all__ = ["Analyzer", "Program"]


class Analyzer(DeclarationPass, TypePass, ConstantEval, ScopePass, ConfigurationPass, StatementPass,
               ExpressionTyping, CallTyping, PassBase):
    """The semantic passes over one build; driver.SEMANTIC_PASSES names the order they run in."""
