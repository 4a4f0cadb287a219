"""The configuration (init/run scheduling tasks), variable and located tables, assertion sites, test entry points.
"""
from __future__ import annotations

import zlib

from .. import types as T
from .base import STATIC, TESTS_UNIT, GenBase, cid, c_string


class ConfigGen(GenBase):
    # ----------------------------------------------------------------- config --
    def config(self) -> None:
        w = self.w
        cfg = self.cfg
        singles = [t for t in cfg.tasks if t.single is not None] if cfg is not None else []
        for k, _t in enumerate(singles):      # SINGLE tasks: an R_TRIG on their BOOL global
            w(f"{STATIC} uint8_t plc_single_prev_{k}, plc_single_fire_{k};")
        w(f"{STATIC} void plc_init(void) {{")
        self.ind += 1
        for k, _t in enumerate(singles):
            w(f"plc_single_prev_{k} = 0;")
        w("plc_fault_rec.kind = PLC_FAULT_NONE;")
        w("plc_fault_rec.pou = NULL;")
        w("plc_fault_rec.file = NULL;")
        w("plc_fault_rec.line = 0;")
        w("plc_fault_rec.col = 0;")
        w("plc_clock = 0;")
        if cfg is not None:
            for g in cfg.globals.values():
                if g.location is not None:
                    w(f"G_{cid(g.name)} = &G_{cid(g.name)}__L;")
                    self.emit_init(f"G_{cid(g.name)}__L", g.type, g.init)
                else:
                    self.emit_init(f"G_{cid(g.name)}", g.type, g.init)
            for inst in cfg.instances:
                w(f"P_{inst.type.name}_init(&{inst.cname});")
        self.ind -= 1
        w("}")
        w()
        w(f"{STATIC} int plc_run(uint64_t tick) {{")
        self.ind += 1
        w("jmp_buf jb;")
        w("if (plc_fault_rec.kind != PLC_FAULT_NONE) return plc_fault_rec.kind;")
        w("plc_jmp_active = &jb;")
        w("if (setjmp(jb) != 0) {")
        w("    plc_jmp_active = NULL;")
        w("    return plc_fault_rec.kind;")
        w("}")
        for k, t in enumerate(singles):
            # sampled at the start of the tick, before any program runs (as MATIEC)
            ref = self.var_ref(t.single)
            w(f"plc_single_fire_{k} = (uint8_t)({ref} && !plc_single_prev_{k});")
            w(f"plc_single_prev_{k} = {ref};")
        if cfg is not None:
            for inst in cfg.instances:
                every = inst.task.every if inst.task is not None else 1
                if inst.task is not None and inst.task.single is not None:
                    w("(void)tick;")
                    w(f"if (plc_single_fire_{singles.index(inst.task)}) P_{inst.type.name}_body(&{inst.cname});")
                elif every > 1:
                    w(f"if (tick % {every}u == 0) P_{inst.type.name}_body(&{inst.cname});")
                else:
                    w("(void)tick;")
                    w(f"P_{inst.type.name}_body(&{inst.cname});")
        else:
            w("(void)tick;")
        w("plc_jmp_active = NULL;")
        w("return 0;")
        self.ind -= 1
        w("}")
        w()
        self.tables()

    def minmax_helpers(self) -> None:
        """The helpers of MIN, MAX and LIMIT, one pair per C type."""
        for suf, ct in (("i8", "int8_t"), ("i16", "int16_t"), ("i32", "int32_t"), ("i64", "int64_t"),
                        ("u8", "uint8_t"), ("u16", "uint16_t"), ("u32", "uint32_t"), ("u64", "uint64_t"),
                        ("f32", "float"), ("f64", "double")):
            self.w(f"static inline {ct} plc_min_{suf}({ct} a, {ct} b) {{ return a < b ? a : b; }}")
            self.w(f"static inline {ct} plc_max_{suf}({ct} a, {ct} b) {{ return a > b ? a : b; }}")

    def var_entries(self):
        """(path, type, retain, constant, c-address, c-type) of every variable, FB instances flattened."""
        cfg = self.cfg
        if cfg is None:
            return []
        out = []
        cname = cfg.name

        def walk(prefix: str, cexpr: str, t: T.Type, retain: bool, constant: bool):
            b = T.resolve_base(t)
            if isinstance(b, T.PouType) and b.scope is not None:
                for v in b.scope.vars.values():
                    if v.section in ("VAR_EXTERNAL", "VAR_TEMP") or v.location is not None:
                        continue
                    walk(f"{prefix}.{v.name}", f"{cexpr}.{cid(v.name)}", v.type, retain or v.retain, v.constant)
                return
            out.append((prefix, T.abi_type(t), int(retain), int(constant), f"&{cexpr}", self.ctype(t),
                        T.signature(t)))

        for g in cfg.globals.values():
            if g.location is not None:
                continue
            walk(f"{cname}.{g.name}", f"G_{cid(g.name)}", g.type, g.retain, g.constant)
        for inst in cfg.instances:
            res = f"{inst.resource}." if inst.resource else ""
            walk(f"{cname}.{res}{inst.name}", inst.cname, inst.type, False, False)
        return out

    def located_entries(self):
        """(location, path, type, c-pointer, retain) of every located variable."""
        cfg = self.cfg
        out = []
        if cfg is None:
            return out
        for g in cfg.globals.values():
            if g.location is not None:
                out.append((g.location, f"{cfg.name}.{g.name}", g.type, f"(void **)&G_{cid(g.name)}",
                            int(g.retain)))
        for inst in cfg.instances:
            for v in inst.type.scope.vars.values():
                if v.location is not None:
                    res = f"{inst.resource}." if inst.resource else ""
                    out.append((v.location, f"{cfg.name}.{res}{inst.name}.{v.name}", v.type,
                                f"(void **)&{inst.cname}.{cid(v.name)}", int(v.retain)))
        return out

    def tables(self) -> None:
        w = self.w
        cfg = self.cfg
        tasks = cfg.tasks if cfg is not None else []
        if tasks:
            w(f"{STATIC} const plc_task_t plc_task_table[] = {{")
            for t in tasks:
                w(f"    {{{c_string(t.name)}, {t.interval_ns}u, {t.every}u, {t.priority}}},")
            w("};")
        located = self.located_entries()
        if located:
            w(f"{STATIC} const plc_located_t plc_located_table[] = {{")
            for loc, path, t, ptr, retain in located:
                index = loc.parts[0]
                bit = loc.parts[1] if loc.size == "X" and len(loc.parts) > 1 else 0
                w(f"    {{{c_string(loc.text)}, {c_string(path)}, '{loc.area}', '{loc.size}', {T.abi_type(t)}, "
                  f"{index}u, {bit}u, {ptr}, {retain}u}},")
            w("};")
        entries = self.var_entries()
        if entries:
            w(f"{STATIC} const plc_var_t plc_var_table[] = {{")
            for path, abi, retain, const, addr, ct, sig in entries:
                w(f"    {{{c_string(path)}, {abi}, {retain}, {const}, (void *){addr}, (uint32_t)sizeof({ct}), "
                  f"{c_string(sig)}}},")
            w("};")
        h = zlib.crc32("\n".join(f"{p}:{a}:{ct}" for p, a, r, c, _ad, ct, _s in entries if r).encode())
        w("const plc_program_t plc_program = {")
        w("    PLC_ABI_VERSION,")
        w(f"    {c_string(cfg.decl.text) if cfg else 'NULL'},")
        w(f"    {cfg.base_tick_ns if cfg else 0}u,")
        w(f"    {'plc_task_table' if tasks else 'NULL'}, {len(tasks)}u,")
        w(f"    {'plc_located_table' if located else 'NULL'}, {len(located)}u,")
        w(f"    {'plc_var_table' if entries else 'NULL'}, {len(entries)}u,")
        w(f"    {h}u,")
        w("    plc_init,")
        w("    plc_run,")
        w("    &plc_clock,")
        w("    &plc_fault_rec,")
        w("};")

    def emit_sites(self) -> None:
        w = self.w
        sites = self.p.sites
        w("const plc_site_t plc_sites[] = {")
        for s in sites:
            w(f"    {{{c_string(s.pos.file)}, {s.pos.line}, {s.pos.col}, {c_string(s.pou)}}},")
        if not sites:
            w("    {NULL, 0, 0, NULL},")
        w("};")
        w(f"const uint32_t plc_n_sites = {len(sites)}u;")

    # ------------------------------------------------------------------ tests --
    def tests(self) -> None:
        w = self.w
        ctx_t = self.p.types.get("ST_TESTCONTEXT")
        tests = [pt for pt in self.p.pous.values() if pt.kind == "FUNCTION_BLOCK" and pt.name.startswith("TEST_")]
        self.test_list = []
        for pt in tests:
            ctx = next((v for v in pt.scope.vars.values() if v.section == "VAR_IN_OUT" and v.type is ctx_t), None)
            if ctx is None:
                continue
            self.test_list.append(pt)
            f = cid(ctx.name)
            if self.split:      # the entry points are in the test's own unit
                with self.piece(f"T_{pt.name}_init", f"T_{pt.name}_body"):
                    w(f"{self.linkage} void T_{pt.name}_init(void *self);")
                    w(f"{self.linkage} int T_{pt.name}_body(void *self, void *ctx);")
            with self.piece(unit=pt.pou.pos.file if self.split else TESTS_UNIT):
                w(f"{self.linkage} void T_{pt.name}_init(void *self) {{ P_{pt.name}_init((P_{pt.name} *)self); }}")
                w(f"{self.linkage} int T_{pt.name}_body(void *self, void *ctx) {{")
                w(f"    P_{pt.name} *s = (P_{pt.name} *)self;")
                w("    jmp_buf jb;")
                w("    plc_jmp_active = &jb;")
                w(f"    s->{f} = *(S_ST_TESTCONTEXT *)ctx;")
                w("    if (setjmp(jb) != 0) {")
                w("        plc_jmp_active = NULL;")
                w(f"        *(S_ST_TESTCONTEXT *)ctx = s->{f};")
                w("        return plc_fault_rec.kind;")
                w("    }")
                w(f"    P_{pt.name}_body(s);")
                w(f"    *(S_ST_TESTCONTEXT *)ctx = s->{f};")
                w("    plc_jmp_active = NULL;")
                w("    return 0;")
                w("}")
        with self.piece(unit=TESTS_UNIT):
            self.test_table(ctx_t)

    def test_table(self, ctx_t) -> None:
        w = self.w
        w("const plc_test_t plc_tests[] = {")
        for pt in self.test_list:
            w(f"    {{{c_string(pt.pou.text)}, {c_string(pt.pou.pos.file)}, {pt.pou.pos.line}, sizeof(P_{pt.name}), "
              f"T_{pt.name}_init, T_{pt.name}_body}},")
        if not self.test_list:
            w("    {NULL, NULL, 0, 0, NULL, NULL},")
        w("};")
        w(f"const uint32_t plc_n_tests = {len(self.test_list)}u;")
        if ctx_t is not None:
            S = "S_ST_TESTCONTEXT"
            fields = ["SCAN", "NOW", "CYCLETIME", "BUDGET", "ADVANCE", "DONE", "FAILURES", "ASSERTS",
                      "LASTMESSAGE", "LASTEXPECTED", "LASTACTUAL"]
            offs = ", ".join(f"offsetof({S}, {f})" for f in fields)
            w(f"const plc_test_ctx_layout_t plc_test_ctx_layout = {{sizeof({S}), {offs}}};")
