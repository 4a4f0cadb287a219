"""The semantic passes, one class per module over one shared state (see sema.py for how they run and
driver.SEMANTIC_PASSES for their order):

context        the Program they build, SemanticState (what they share) and Pass (their base)
declarations   pass 1: names of types, POUs, configurations
typedecls      pass 2: type declarations and type specs
scopes         pass 3: variable scopes, declarations, locations, initial values
configuration  pass 4: configuration, resources, tasks, instances
externals      pass 5: VAR_EXTERNAL binding
statements     pass 6: POU bodies, statement by statement
expressions    expression typing for pass 6
calls          call typing and argument binding for pass 6; assignment compatibility
constants      compile-time constant evaluation, used by every pass
"""
