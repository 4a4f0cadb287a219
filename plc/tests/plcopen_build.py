"""Build PLCopen TC6 XML test projects in the shape OpenPLC Editor and Beremiz write them.

Elements carry positions, relPositions and wire points like the editors' files; only what a test
names is variable.  `src` arguments are a localId, a (localId, formalParameter) pair or a list of
them (a wired OR).  `project(...)` wraps POUs into a whole file with header and configuration.
"""
from __future__ import annotations

from xml.sax.saxutils import escape

HEAD = """<?xml version='1.0' encoding='utf-8'?>
<project xmlns:ns1="http://www.plcopen.org/xml/tc6_0201" xmlns:xhtml="http://www.w3.org/1999/xhtml" \
xmlns:xsd="http://www.w3.org/2001/XMLSchema" xmlns="http://www.plcopen.org/xml/tc6_0201">
  <fileHeader companyName="atc-plc tests" productName="{name}" productVersion="1" \
creationDateTime="2026-12-01T09:00:00"/>
  <contentHeader name="{name}" modificationDateTime="2026-12-01T09:00:00">
    <coordinateInfo>
      <fbd><scaling x="10" y="10"/></fbd>
      <ld><scaling x="10" y="10"/></ld>
      <sfc><scaling x="10" y="10"/></sfc>
    </coordinateInfo>
  </contentHeader>
"""


def _conns(src, x: float, y: float) -> str:
    if src is None:
        return ""
    items = src if isinstance(src, list) else [src]
    out = []
    for s in items:
        ref, pin = (s if isinstance(s, tuple) else (s, None))
        fp = f' formalParameter="{pin}"' if pin else ""
        out.append(f'<connection refLocalId="{ref}"{fp}><position x="{x}" y="{y}"/>'
                   f'<position x="{x - 20}" y="{y}"/></connection>')
    return "".join(out)


def point_in(src, x=0, y=0) -> str:
    return f'<connectionPointIn><relPosition x="0" y="10"/>{_conns(src, x, y + 10)}</connectionPointIn>'


def point_out() -> str:
    return '<connectionPointOut><relPosition x="30" y="10"/></connectionPointOut>'


class Body:
    """The elements of one LD or FBD body."""

    def __init__(self, language: str = "LD"):
        self.language = language
        self.items: list[str] = []

    def _order(self, order: int | None) -> str:
        return f' executionOrderId="{order}"' if order is not None else ""

    def left_rail(self, lid: int, y: float = 0, points: int = 1, x: float = 20) -> "Body":
        outs = "".join(f'<connectionPointOut formalParameter=""><relPosition x="10" y="{20 + 40 * k}"/>'
                       '</connectionPointOut>' for k in range(points))
        self.items.append(f'<leftPowerRail localId="{lid}" height="{40 * points}" width="10">'
                          f'<position x="{x}" y="{y}"/>{outs}</leftPowerRail>')
        return self

    def right_rail(self, lid: int, srcs: list, y: float = 0, x: float = 800) -> "Body":
        ins = "".join(f'<connectionPointIn><relPosition x="0" y="{20 + 40 * k}"/>{_conns(s, x, y + 20 + 40 * k)}'
                      '</connectionPointIn>' for k, s in enumerate(srcs))
        self.items.append(f'<rightPowerRail localId="{lid}" height="{40 * max(1, len(srcs))}" width="10">'
                          f'<position x="{x}" y="{y}"/>{ins}</rightPowerRail>')
        return self

    def contact(self, lid: int, var: str, src, x: float = 100, y: float = 0, negated: bool = False,
                edge: str | None = None, order: int | None = None) -> "Body":
        e = f' edge="{edge}"' if edge else ""
        self.items.append(f'<contact localId="{lid}" height="20" width="30" negated="{str(negated).lower()}"{e}'
                          f'{self._order(order)}><position x="{x}" y="{y}"/>{point_in(src, x, y)}{point_out()}'
                          f'<variable>{escape(var)}</variable></contact>')
        return self

    def coil(self, lid: int, var: str, src, x: float = 300, y: float = 0, negated: bool = False,
             storage: str | None = None, edge: str | None = None, order: int | None = None) -> "Body":
        s = f' storage="{storage}"' if storage else ""
        e = f' edge="{edge}"' if edge else ""
        self.items.append(f'<coil localId="{lid}" height="20" width="30" negated="{str(negated).lower()}"{s}{e}'
                          f'{self._order(order)}><position x="{x}" y="{y}"/>{point_in(src, x, y)}{point_out()}'
                          f'<variable>{escape(var)}</variable></coil>')
        return self

    def block(self, lid: int, type_name: str, inputs: dict, outputs: list[str], x: float = 200, y: float = 0,
              instance: str | None = None, order: int | None = None, negated_in=(), negated_out=(),
              edge_in: dict | None = None) -> "Body":
        inst = f' instanceName="{instance}"' if instance else ""
        ins = []
        for pin, src in inputs.items():
            neg = ' negated="true"' if pin in negated_in else ""
            edge = f' edge="{edge_in[pin]}"' if edge_in and pin in edge_in else ""
            ins.append(f'<variable formalParameter="{pin}"{neg}{edge}>{point_in(src, x, y)}</variable>')
        outs = "".join(f'<variable formalParameter="{pin}"{NEG if pin in negated_out else ""}>'
                       f'{point_out()}</variable>' for pin in outputs)
        self.items.append(f'<block localId="{lid}" typeName="{type_name}"{inst} width="80" height="60"'
                          f'{self._order(order)}><position x="{x}" y="{y}"/>'
                          f'<inputVariables>{"".join(ins)}</inputVariables><inOutVariables/>'
                          f'<outputVariables>{outs}</outputVariables></block>')
        return self

    def in_var(self, lid: int, expr: str, x: float = 50, y: float = 0, negated: bool = False,
               order: int | None = None) -> "Body":
        self.items.append(f'<inVariable localId="{lid}" height="30" width="60" negated="{str(negated).lower()}"'
                          f'{self._order(order)}><position x="{x}" y="{y}"/>{point_out()}'
                          f'<expression>{escape(expr)}</expression></inVariable>')
        return self

    def out_var(self, lid: int, expr: str, src, x: float = 400, y: float = 0, negated: bool = False,
                order: int | None = None) -> "Body":
        self.items.append(f'<outVariable localId="{lid}" height="30" width="60" negated="{str(negated).lower()}"'
                          f'{self._order(order)}><position x="{x}" y="{y}"/>{point_in(src, x, y)}'
                          f'<expression>{escape(expr)}</expression></outVariable>')
        return self

    def in_out_var(self, lid: int, expr: str, src, x: float = 300, y: float = 0) -> "Body":
        self.items.append(f'<inOutVariable localId="{lid}" height="30" width="60" negatedOut="false" '
                          f'negatedIn="false"><position x="{x}" y="{y}"/>{point_in(src, x, y)}{point_out()}'
                          f'<expression>{escape(expr)}</expression></inOutVariable>')
        return self

    def connector(self, lid: int, name: str, src, x: float = 300, y: float = 0) -> "Body":
        self.items.append(f'<connector localId="{lid}" name="{name}" height="20" width="80">'
                          f'<position x="{x}" y="{y}"/>{point_in(src, x, y)}</connector>')
        return self

    def continuation(self, lid: int, name: str, x: float = 50, y: float = 0) -> "Body":
        self.items.append(f'<continuation localId="{lid}" name="{name}" height="20" width="80">'
                          f'<position x="{x}" y="{y}"/>{point_out()}</continuation>')
        return self

    def jump(self, lid: int, label: str, src, x: float = 300, y: float = 0) -> "Body":
        self.items.append(f'<jump localId="{lid}" label="{label}" height="20" width="60">'
                          f'<position x="{x}" y="{y}"/>{point_in(src, x, y)}</jump>')
        return self

    def label(self, lid: int, label: str, y: float = 0, order: int | None = None) -> "Body":
        self.items.append(f'<label localId="{lid}" label="{label}" height="20" width="60"{self._order(order)}>'
                          f'<position x="20" y="{y}"/></label>')
        return self

    def ret(self, lid: int, src, x: float = 300, y: float = 0) -> "Body":
        self.items.append(f'<return localId="{lid}" height="20" width="60"><position x="{x}" y="{y}"/>'
                          f'{point_in(src, x, y)}</return>')
        return self

    def comment(self, lid: int, text: str, y: float = 0) -> "Body":
        self.items.append(f'<comment localId="{lid}" height="40" width="300"><position x="20" y="{y}"/>'
                          f'<content><xhtml:p><![CDATA[{text}]]></xhtml:p></content></comment>')
        return self

    def xml(self) -> str:
        return f"<{self.language}>" + "\n".join(self.items) + f"</{self.language}>"


def variables(section: str, decls: list[tuple]) -> str:
    """decls: (name, type) or (name, type, initial value)."""
    out = []
    for d in decls:
        name, t = d[0], d[1]
        tx = f"<{t}/>" if t.isupper() and t.replace("_", "").isalnum() and t in ELEMENTARY else \
            f'<derived name="{t}"/>'
        init = f'<initialValue><simpleValue value="{escape(d[2])}"/></initialValue>' if len(d) > 2 else ""
        out.append(f'<variable name="{name}"><type>{tx}</type>{init}</variable>')
    return f"<{section}>" + "".join(out) + f"</{section}>"


NEG = ' negated="true"'
ELEMENTARY = {"BOOL", "INT", "DINT", "UINT", "WORD", "TIME", "REAL", "SINT", "BYTE"}


def pou(name: str, kind: str, body, inputs=(), outputs=(), locals_=(), ret: str | None = None) -> str:
    iface = []
    if ret:
        iface.append(f"<returnType><{ret}/></returnType>")
    if inputs:
        iface.append(variables("inputVars", list(inputs)))
    if outputs:
        iface.append(variables("outputVars", list(outputs)))
    if locals_:
        iface.append(variables("localVars", list(locals_)))
    body_xml = body.xml() if isinstance(body, Body) else \
        f"<ST><xhtml:p><![CDATA[{body}]]></xhtml:p></ST>"
    return (f'<pou name="{name}" pouType="{kind}"><interface>{"".join(iface)}</interface>'
            f"<body>{body_xml}</body></pou>")


def project(pous: list[str], name: str = "test", data_types: str = "", config: str | None = None) -> str:
    cfg = config or ""
    return (HEAD.format(name=name) + f"  <types><dataTypes>{data_types}</dataTypes><pous>" + "\n".join(pous)
            + f"</pous></types>\n  <instances><configurations>{cfg}</configurations></instances>\n</project>\n")
