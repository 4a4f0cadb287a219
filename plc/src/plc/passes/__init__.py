"""The semantic passes, one concern per module (see sema.py for how they join and driver.SEMANTIC_PASSES for
the order they run in):

context        the Program they build and the state they share
declarations   pass 1: names of types, POUs, configurations
typedecls      pass 2: type declarations and type specs
scopes         pass 3: variable scopes, declarations, locations, initial values
configuration  passes 4-5: configuration, resources, tasks, instances; VAR_EXTERNAL binding
statements     pass 6: POU bodies, statement by statement
expressions    expression typing for pass 6
calls          call typing and argument binding for pass 6; assignment compatibility
constants      compile-time constant evaluation, used by every pass
"""
