"""Pass 4, configuration: resources, tasks, program instances, configuration globals.
"""
from __future__ import annotations

import math
from functools import reduce

from .. import ast as A
from .. import types as T
from ..symbols import Scope, VarSym
from .context import Pass, TaskInfo, InstanceInfo, ConfigInfo


class ConfigurationPass(Pass):
    pass_name = "configuration"

    def run(self) -> None:
        for cfg in (i for f in self.st.files for i in f.items if isinstance(i, A.Configuration)):
            self.configuration(cfg)

    def configuration(self, cfg: A.Configuration) -> None:
        info = ConfigInfo(cfg.name, cfg)
        self.st.prog.configs.append(info)
        gscope = Scope(cfg.name, "CONFIGURATION")
        self.st.scope = gscope
        for block in cfg.globals:
            self.scope_pass.var_block(block, gscope, None)
        tasks: dict[str, TaskInfo] = {}
        for res in cfg.resources:
            info.resources.append(res.name)
            for block in res.globals:
                self.scope_pass.var_block(block, gscope, None)
            for td in res.tasks:
                if td.name in tasks:
                    self.err(td.pos, f"duplicate task '{td.text}'")
                    continue
                single = None
                if td.single is not None:
                    st = self.expr_typing.expr(td.single, gscope, T.BOOL)
                    sym = td.single.sym
                    if not isinstance(td.single, A.Name) or not isinstance(sym, VarSym) or not T.is_elem(st, "bool"):
                        self.err(td.single.pos, "SINGLE needs a BOOL global variable",
                                 "TASK ev(SINGLE := trigger, PRIORITY := 1); with trigger in VAR_GLOBAL")
                    else:
                        single = sym
                interval = 0
                if td.interval is not None:
                    self.expr_typing.expr(td.interval, gscope, T.TIME)
                    v = self.const_eval.const_value(td.interval)
                    if not isinstance(td.interval, A.TimeLit) or v is None or v <= 0:
                        self.err(td.interval.pos, "INTERVAL must be a positive TIME literal", "INTERVAL := T#10ms")
                    elif single is None:       # as MATIEC, SINGLE wins: the task runs on rising edges only
                        interval = v
                elif td.single is None:
                    self.err(td.pos, f"task '{td.text}' has neither INTERVAL nor SINGLE",
                             "TASK t(INTERVAL := T#10ms, PRIORITY := 0);")
                prio = 0
                if td.priority is not None:
                    p = self.const_eval.const_int(td.priority)
                    if p is None or p < 0:
                        self.err(td.priority.pos, "PRIORITY must be a non-negative integer")
                    else:
                        prio = p
                ti = TaskInfo(td.name, interval, prio, td.pos, single=single)
                tasks[td.name] = ti
                info.tasks.append(ti)
            for pi in res.programs:
                pt = self.st.prog.pous.get(pi.type_name)
                if pt is None or pt.kind != "PROGRAM":
                    programs = [n for n, p in self.st.prog.pous.items() if p.kind == "PROGRAM"]
                    self.err(pi.pos, f"unknown PROGRAM '{pi.type_text}'",
                             self.type_pass.suggest(pi.type_name, programs))
                    continue
                task = None
                if pi.task is None:
                    self.port(pi.pos, "no-task", instance=pi.text)
                if not res.name:
                    self.port(pi.pos, "no-resource")
                if pi.task is not None:
                    task = tasks.get(pi.task)
                    if task is None:
                        self.err(pi.pos, f"unknown task '{pi.task}'")
                if pi.args:
                    self.err(pi.args[0].pos, "program instance parameters are not supported",
                             "connect the program through VAR_EXTERNAL / located variables")
                if any(i.name == pi.name for i in info.instances) or pi.name in gscope.vars:
                    self.err(pi.pos, f"duplicate program instance '{pi.text}'")
                    continue
                info.instances.append(InstanceInfo(pi.name, pt, task, res.name, pi.pos))
        intervals = [t.interval_ns for t in info.tasks if t.interval_ns > 0]
        info.base_tick_ns = reduce(math.gcd, intervals) if intervals else 0
        if not intervals and any(t.single is not None for t in info.tasks):
            self.err(cfg.pos, "a configuration needs at least one periodic task (INTERVAL) to set the scan tick")
        for t in info.tasks:
            if info.base_tick_ns and t.interval_ns:
                t.every = t.interval_ns // info.base_tick_ns
        info.globals = gscope.vars
        for v in gscope.vars.values():
            self.st.global_scope[v.name] = v
        self.st.scope = None
