"""The IEC type system as the semantic passes and the C generator see it."""
from __future__ import annotations

from dataclasses import dataclass, field


class Type:
    @property
    def base(self) -> "Type":
        return self

    def __str__(self) -> str:
        return getattr(self, "name", "?")


@dataclass(eq=False)
class Elementary(Type):
    name: str
    ctype: str
    size: int            # bytes
    cat: str             # bool int uint bit real time date tod dt string
    bits: int = 0
    lo: int = 0
    hi: int = 0
    abi: str = "PLC_T_OTHER"

    @property
    def is_int(self) -> bool:
        return self.cat in ("int", "uint")

    @property
    def is_signed(self) -> bool:
        return self.cat == "int"

    @property
    def is_bit(self) -> bool:
        return self.cat in ("bit", "bool")

    @property
    def is_real(self) -> bool:
        return self.cat == "real"

    @property
    def is_num(self) -> bool:
        return self.cat in ("int", "uint", "real")

    @property
    def is_time(self) -> bool:
        return self.cat in ("time", "date", "tod", "dt")


def _int(name, ctype, bits, signed, abi):
    if signed:
        lo, hi = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    else:
        lo, hi = 0, (1 << bits) - 1
    return Elementary(name, ctype, bits // 8, "int" if signed else "uint", bits, lo, hi, abi)


def _bit(name, ctype, bits, abi):
    return Elementary(name, ctype, max(1, bits // 8), "bit", bits, 0, (1 << bits) - 1, abi)


BOOL = Elementary("BOOL", "uint8_t", 1, "bool", 1, 0, 1, "PLC_T_BOOL")
SINT = _int("SINT", "int8_t", 8, True, "PLC_T_SINT")
INT = _int("INT", "int16_t", 16, True, "PLC_T_INT")
DINT = _int("DINT", "int32_t", 32, True, "PLC_T_DINT")
LINT = _int("LINT", "int64_t", 64, True, "PLC_T_LINT")
USINT = _int("USINT", "uint8_t", 8, False, "PLC_T_USINT")
UINT = _int("UINT", "uint16_t", 16, False, "PLC_T_UINT")
UDINT = _int("UDINT", "uint32_t", 32, False, "PLC_T_UDINT")
ULINT = _int("ULINT", "uint64_t", 64, False, "PLC_T_ULINT")
BYTE = _bit("BYTE", "uint8_t", 8, "PLC_T_BYTE")
WORD = _bit("WORD", "uint16_t", 16, "PLC_T_WORD")
DWORD = _bit("DWORD", "uint32_t", 32, "PLC_T_DWORD")
LWORD = _bit("LWORD", "uint64_t", 64, "PLC_T_LWORD")
REAL = Elementary("REAL", "float", 4, "real", 32, 0, 0, "PLC_T_REAL")
LREAL = Elementary("LREAL", "double", 8, "real", 64, 0, 0, "PLC_T_LREAL")
TIME = Elementary("TIME", "int64_t", 8, "time", 64, 0, 0, "PLC_T_TIME")
DATE = Elementary("DATE", "int64_t", 8, "date", 64, 0, 0, "PLC_T_DATE")
TOD = Elementary("TOD", "int64_t", 8, "tod", 64, 0, 0, "PLC_T_TOD")
DT = Elementary("DT", "int64_t", 8, "dt", 64, 0, 0, "PLC_T_DT")
STRING = Elementary("STRING", "plc_string_t", 128, "string", 0, 0, 0, "PLC_T_STRING")

ELEMENTARY = {t.name: t for t in (BOOL, SINT, INT, DINT, LINT, USINT, UINT, UDINT, ULINT, BYTE, WORD, DWORD,
                                  LWORD, REAL, LREAL, TIME, DATE, TOD, DT, STRING)}
ELEMENTARY["TIME_OF_DAY"] = TOD
ELEMENTARY["DATE_AND_TIME"] = DT

# Names of elementary types that exist in the standard but that we (and OpenPLC) do not support.
UNSUPPORTED = {"WSTRING": "WSTRING is not supported by OpenPLC", "LTIME": "LTIME is not supported by MATIEC",
               "LDATE": "LDATE is not supported by MATIEC", "LTOD": "LTOD is not supported by MATIEC",
               "LDT": "LDT is not supported by MATIEC", "CHAR": "CHAR is not supported by MATIEC",
               "WCHAR": "WCHAR is not supported by MATIEC"}

# Generic type names usable only in the standard library signatures.
GENERIC = ("ANY", "ANY_INT", "ANY_NUM", "ANY_REAL", "ANY_BIT", "ANY_ELEMENTARY", "ANY_MAGNITUDE", "ANY_STRING")


@dataclass(eq=False)
class LiteralType(Type):
    """The type of an untyped literal before context fixes it (ANY_INT or ANY_REAL)."""
    name: str
    cat: str          # "int" | "real"


ANY_INT_LIT = LiteralType("ANY_INT", "int")
ANY_REAL_LIT = LiteralType("ANY_REAL", "real")


@dataclass(eq=False)
class EnumType(Type):
    name: str
    values: list[str]
    ctype: str = "int32_t"
    size: int = 4
    abi: str = "PLC_T_ENUM"


@dataclass(eq=False)
class SubrangeType(Type):
    name: str
    of: Elementary
    lo: int
    hi: int

    @property
    def base(self) -> Type:
        return self.of


@dataclass(eq=False)
class ArrayType(Type):
    dims: list[tuple[int, int]]
    elem: Type
    cname: str = ""

    @property
    def name(self) -> str:  # type: ignore[override]
        d = ", ".join(f"{lo}..{hi}" for lo, hi in self.dims)
        return f"ARRAY[{d}] OF {self.elem}"

    def count(self) -> int:
        n = 1
        for lo, hi in self.dims:
            n *= hi - lo + 1
        return n


@dataclass(eq=False)
class StructMemberT:
    name: str
    type: Type
    init: object = None
    pos: object = None


@dataclass(eq=False)
class StructType(Type):
    name: str
    members: dict[str, StructMemberT] = field(default_factory=dict)
    cname: str = ""
    decl: object = None


@dataclass(eq=False)
class StringType(Type):
    """STRING with an explicit length (an extension: OpenPLC crashes on STRING[n])."""
    length: int

    @property
    def name(self) -> str:  # type: ignore[override]
        return f"STRING[{self.length}]"

    @property
    def base(self) -> Type:
        return STRING


@dataclass(eq=False)
class PouType(Type):
    """A FUNCTION_BLOCK or PROGRAM used as the type of an instance."""
    name: str
    pou: object               # ast.Pou
    kind: str                 # FUNCTION_BLOCK | PROGRAM
    scope: object = None      # sema.Scope of its variables
    cname: str = ""
    builtin: bool = False


@dataclass(eq=False)
class PointerType(Type):
    target: Type

    @property
    def name(self) -> str:  # type: ignore[override]
        return f"POINTER TO {self.target}"


class ErrorType(Type):
    """Stands in after an error so one mistake does not cascade into many."""
    name = "<error>"


ERROR = ErrorType()


def resolve_base(t: Type) -> Type:
    """Strip subranges (and sized strings) down to the type they are built on."""
    while isinstance(t, (SubrangeType, StringType)):
        t = t.base
    return t


def is_elem(t: Type, *cats: str) -> bool:
    b = resolve_base(t)
    return isinstance(b, Elementary) and (not cats or b.cat in cats)


def same_type(a: Type, b: Type) -> bool:
    a, b = resolve_base(a), resolve_base(b)
    if a is b:
        return True
    if isinstance(a, ArrayType) and isinstance(b, ArrayType):
        return a.dims == b.dims and same_type(a.elem, b.elem)
    return False


def is_generic_ok(generic: str, t: Type) -> bool:
    b = resolve_base(t)
    if isinstance(b, LiteralType):
        return {"ANY": True, "ANY_ELEMENTARY": True, "ANY_MAGNITUDE": True, "ANY_NUM": True,
                "ANY_INT": b.cat == "int", "ANY_REAL": b.cat == "real", "ANY_BIT": b.cat == "int"}.get(generic, False)
    if isinstance(b, EnumType):
        return generic in ("ANY", "ANY_ELEMENTARY")
    if not isinstance(b, Elementary):
        return generic == "ANY"
    return {
        "ANY": True,
        "ANY_ELEMENTARY": True,
        "ANY_MAGNITUDE": b.cat in ("int", "uint", "real", "time"),
        "ANY_NUM": b.cat in ("int", "uint", "real"),
        "ANY_INT": b.cat in ("int", "uint"),
        "ANY_REAL": b.cat == "real",
        "ANY_BIT": b.cat in ("bit", "bool"),
        "ANY_STRING": b.cat == "string",
    }.get(generic, False)


def abi_type(t: Type) -> str:
    b = resolve_base(t)
    if isinstance(b, Elementary):
        return b.abi
    if isinstance(b, EnumType):
        return "PLC_T_ENUM"
    return "PLC_T_OTHER"


def signature(t: Type) -> str:
    """The full text of a type as retained data record it: two types with the same signature store their
    values alike.  Subranges count as their base type (same storage; the bounds only check assignments)."""
    if isinstance(t, StringType):
        return t.name
    b = resolve_base(t)
    if isinstance(b, EnumType):
        return f"{b.name.upper()}({','.join(v.upper() for v in b.values)})"
    if isinstance(b, ArrayType):
        d = ",".join(f"{lo}..{hi}" for lo, hi in b.dims)
        return f"ARRAY[{d}] OF {signature(b.elem)}"
    if isinstance(b, StructType):
        members = ";".join(f"{m.name.upper()}:{signature(m.type)}" for m in b.members.values())
        return f"{b.name.upper()}{{{members}}}"
    return str(getattr(b, "name", "?")).upper()
