"""The constructs OpenPLC's MATIEC rejects, as facts the compiler's stages record where they meet them.

The lexer, the parser and the semantic passes each meet constructs our compiler takes but MATIEC does not;
they record a `Fact` (`fact(rule, pos, **details)`) and go on.  The portability pass (portability.lint) turns
every fact into its rule's warning.  The rules live here, below every stage, so that the lexer can record a
fact without importing the pass that reads it.
"""
from __future__ import annotations

from dataclasses import dataclass

from .diagnostics import Pos


@dataclass(frozen=True)
class Rule:
    """A portability warning; message and hint are str.format templates over the details of the fact.  A rule
    with a target is reported only when checking for that deploy target (`plc check --target`)."""
    message: str
    hint: str | None = None
    target: str | None = None


# rule -> warning; a warning's diagnostic code is "portability." + its rule (docs/matiec.md lists every rule with
# what MATIEC or OpenPLC does).  The lexer, the parser and the semantic passes record the first group as facts; the
# portability pass finds the second group itself, in the names and statement lists of the program.
RULES: dict[str, Rule] = {
    "anon-enum": Rule("anonymous enumeration in a variable declaration", "declare the enumeration in a TYPE block"),
    "anon-struct": Rule("anonymous STRUCT in a variable declaration", "declare it in a TYPE block"),
    "array-bound": Rule("a named constant as an array bound is not accepted by MATIEC",
                        "write the bound as a literal"),
    "array-of-array": Rule("arrays of arrays break OpenPLC's C build", "use a 2-D array ARRAY[a..b, c..d]"),
    "bit-access": Rule("bit access (w.3) is not accepted by OpenPLC's MATIEC", "use SHR/AND"),
    "call-statement": Rule("a FUNCTION call is not a statement in MATIEC", "use the result: `ok := F(...);`"),
    "case-constant": Rule("a named constant as a CASE label is rejected by MATIEC", "write the value as a literal"),
    "comment-block": Rule("'/* */' comments are not accepted by MATIEC", "use (* ... *)"),
    "comment-line": Rule("'//' comments are not accepted by MATIEC", "use (* ... *)"),
    "empty-call": Rule("a call with no arguments F() is not accepted by MATIEC"),
    "enum-base": Rule("enumerations with a base type are IEC edition 3"),
    "enum-order": Rule("'{op}' on enumeration values is rejected by MATIEC", "compare with = or <>"),
    "enum-qualify": Rule("'{value}' is a value of several enumerations ({enums}); MATIEC needs it qualified",
                         "write {enum}#{value}"),
    "enum-select": Rule("{call} of enumeration values is rejected by MATIEC (no overload takes them)",
                        "choose with IF ... THEN x := a; ELSE x := b; END_IF"),
    "enum-value": Rule("enumeration values with explicit numbers are not accepted by MATIEC", "remove ':= n'"),
    "fb-array": Rule("arrays of function block instances are not supported by MATIEC"),
    "fb-inout": Rule("a function block instance passed as VAR_IN_OUT is not supported by MATIEC"),
    "generic-conversion": Rule("generic conversion {call} is IEC edition 3; OpenPLC needs <TYPE>_TO_{type}"),
    "global": Rule("VAR_GLOBAL outside a CONFIGURATION is not accepted by MATIEC",
                   "declare globals inside CONFIGURATION or RESOURCE"),
    "global-fb": Rule("function block instances in VAR_GLOBAL break OpenPLC's C build",
                      "declare the instance in the PROGRAM"),
    "inout-element": Rule("an array element as a FUNCTION's VAR_IN_OUT breaks OpenPLC's C build",
                          "copy it to a variable and back"),
    "member-named-like-type": Rule("member '{member}' is named like its type: OpenPLC's g++ rejects the C that "
                                   "MATIEC makes of it", "give the member another name"),
    "mixed-located": Rule("a VAR block mixing located and unlocated variables is rejected by MATIEC",
                          "put the located variables in a VAR block of their own"),
    "no-resource": Rule("TASK and PROGRAM directly in the CONFIGURATION are rejected by MATIEC",
                        "put them in RESOURCE Res0 ON PLC"),
    "no-task": Rule("program instance '{instance}' has no task: MATIEC rejects it", "PROGRAM inst WITH task : Type;"),
    "openplc-time-negate": Rule("unary '-' on a {type}: MATIEC takes it, but OpenPLC's g++ rejects the C it makes "
                                "of it (IEC_TIMESPEC has no unary minus)", "subtract it from T#0s: T#0s - x for -x",
                                "openplc"),
    "power": Rule("the '**' operator is missing in OpenPLC", "use EXPT(a, b)"),
    "pragma": Rule("pragma {{...}} ignored here, but MATIEC pastes it into its C output", "remove it"),
    "string-length": Rule("STRING[n] is not supported by OpenPLC (a bare declaration crashes iec2c)",
                          "use plain STRING (126 characters)"),
    "string-literal": Rule("a string literal of 126 characters breaks OpenPLC's C build (125 at most)"),
    "struct-array-init": Rule("initialisers of arrays of structures break OpenPLC's C build",
                              "initialise the elements in code"),
    "subrange-default": Rule("MATIEC starts an inline subrange variable at 0, not at its lower bound {lo}",
                             "give it an initial value, or declare the subrange as a TYPE"),
    "time-conversion": Rule("{call} counts seconds in OpenPLC's MATIEC and milliseconds in STruC++ (OpenPLC v4)",
                            "keep durations as TIME and compare TIME values"),
    "time-inexact": Rule("OpenPLC v3 makes T#{text} {openplc} ns, not {exact} ns: its __time_to_timespec truncates "
                         "(x86-64), so a sum of it drifts and a comparison with it can flip", "{hint}"),
    "time-syntax": Rule("MATIEC rejects the duration T#{text}: its units follow one another (d h m s ms) and each "
                        "after the first stays in range (h < 24, m and s < 60, ms < 1000)", "write {spelling}"),
    "result-access": Rule("a member or element of {what} is a syntax error in MATIEC (it selects from variables "
                          "only)", "assign it to a variable first and select from that"),
    "time-unit": Rule("'us'/'ns' units in TIME literals are rejected by OpenPLC's MATIEC",
                      "write fractions of ms, e.g. T#1.5ms"),
    "unary-chain": Rule("'{op}' directly before another '{inner}' is a syntax error in MATIEC",
                        "put the inner operation in parentheses: {op} ({inner} x)"),
    "unary-plus": Rule("a unary '+' other than the sign of a number is a syntax error in MATIEC",
                       "leave the '+' out"),
    "wstring": Rule("double-quoted WSTRING literals are not supported by OpenPLC"),
    # found by the portability pass
    "empty-body": Rule("no statement in {where}: MATIEC rejects an empty statement list",
                       "put at least one statement there"),
    "empty-statement": Rule("an empty statement ';' is rejected by MATIEC"),
    "enum-value-name": Rule("enumeration value '{value}' is {clash}: MATIEC rejects it", "choose another name"),
    "function-without-vars": Rule("FUNCTION {function} declares no variables: MATIEC does not recognise it as a "
                                  "function", "declare at least one VAR_INPUT or VAR block"),
    "identifier-double-underscore": Rule("identifier '{name}' contains '__' (reserved by MATIEC's C output)"),
    "identifier-trailing-underscore": Rule("identifier '{name}' ends with '_' (rejected by MATIEC)"),
    "library-name": Rule("{what} name '{name}' collides with OpenPLC's library (iec2c -p fails or crashes)",
                         "rename it, e.g. with a prefix FB_, F_, E_ or ST_"),
    "openplc-configuration": Rule("OpenPLC needs CONFIGURATION Config0 (found '{name}')"),
    "openplc-resource": Rule("OpenPLC needs RESOURCE Res0 (found '{name}')"),
    "type-alias": Rule("TYPE {type} renames {kind} ({aliased}): MATIEC's C output does not compile",
                       "use {aliased} itself"),
    "type-order": Rule("TYPE {type} uses {used}, which this file declares further down (line {line}): MATIEC reads "
                       "a file in order and rejects it", "declare {used} before {type}"),
    "var-keyword": Rule("variable '{name}' is a keyword to MATIEC"),
    "var-library-block": Rule("variable '{name}' is named like a function block of OpenPLC's library"),
    "var-own-type-name": Rule("variable '{name}' is named like its own type (differing only in case)",
                              "choose another name"),
    "var-std-name": Rule("variable '{name}' is named like a standard function"),
    "var-type-name": Rule("variable '{name}' is named like a type", "choose another name"),
    # STruC++, the compiler of OpenPLC v4 (--target openplc-v4): the lexer and the parser record the first three,
    # the portability pass finds the others
    "strucpp-enum-literal": Rule("STruC++ (OpenPLC v4) rejects the enumeration literal {text}: its lexer stops at "
                                 "the '#'", "write {value} alone (MATIEC takes it when no other enumeration "
                                 "declares {value}); STruC++'s {enum}.{value} is not MATIEC's", "openplc-v4"),
    "strucpp-bool-literal": Rule("STruC++ (OpenPLC v4) rejects the literal {text}: its lexer stops at the '#' "
                                 "before TRUE or FALSE", "write {value} alone (every compiler takes it)",
                                 "openplc-v4"),
    "strucpp-negative-time": Rule("STruC++ (OpenPLC v4) rejects the negative TIME literal {text}",
                                  "write T#0s - {positive}: MATIEC, OpenPLC's C and STruC++ all take it "
                                  "(-{positive} does not compile in OpenPLC v3)", "openplc-v4"),
    "strucpp-nested-comment": Rule("'(*' inside a comment: STruC++ (OpenPLC v4) nests comments, so this one ends "
                                   "at a later '*)' (or never), where MATIEC and plc end it at the first",
                                   "write the inner text without '(*'", "openplc-v4"),
    "strucpp-case-label": Rule("STruC++ (OpenPLC v4) does not see this CASE arm: {why}",
                               "split the arm: a label starts with a number, '-' or a name, and ':' comes "
                               "within 8 tokens (at most 4 plain labels)", "openplc-v4"),
    "strucpp-keyword": Rule("'{name}' is a keyword to STruC++ (OpenPLC v4)", "choose another name", "openplc-v4"),
    "strucpp-library-call": Rule("function block instance '{name}' is named like the function {function} of the "
                                 "libraries STruC++ (OpenPLC v4) loads: it calls the function, not the instance",
                                 "choose another name", "openplc-v4"),
    "strucpp-and-guard": Rule("STruC++ (OpenPLC v4) evaluates both operands of {op}: {array}[...] is read even when "
                              "the left operand already decides, and an index out of its bounds stops the program "
                              "there (an exception), where MATIEC and plc skip the read",
                              "read {array}[...] inside an IF that checks {index} first", "openplc-v4"),
    "strucpp-string-call": Rule("STruC++ (OpenPLC v4) has no C++ for {call} of {why}: g++ refuses it", "{hint}",
                                "openplc-v4"),
    "strucpp-string-length": Rule("the result of {call} can be longer than 126 characters: a plain STRING keeps 126 "
                                  "in OpenPLC v3 (MATIEC) and 254 in STruC++ (OpenPLC v4)",
                                  "cut it the same on both: LEFT({call}(...), 126)", "openplc-v4"),
    "strucpp-not-int": Rule("STruC++ (OpenPLC v4) writes the {op} under this NOT as C++ '{cpp}' of {operands}, "
                            "which gives an int, and its NOT takes bit types only: g++ refuses the C++",
                            "give the {op} to a variable and write NOT of that variable, or for comparisons apply De "
                            "Morgan (NOT (a <> 0 AND b = c) is a = 0 OR b <> c): MATIEC, plc and STruC++ all take "
                            "both", "openplc-v4"),
}


def rule_code(rule: str) -> str:
    """The diagnostic code of a rule's warning."""
    return "portability." + rule


@dataclass(frozen=True)
class Fact:
    """A construct OpenPLC's MATIEC rejects, recorded by the stage that met it: the rule of RULES, where, and
    the details the rule's message names.  The portability pass makes it the rule's warning."""
    rule: str
    pos: Pos
    details: tuple[tuple[str, str], ...] = ()


def fact(rule: str, pos: Pos, **details: str) -> Fact:
    """The fact that the construct of `rule` is at `pos` (an unknown rule is a compiler bug: KeyError)."""
    RULES[rule]
    return Fact(rule, pos, tuple(details.items()))
