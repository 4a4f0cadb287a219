"""The C generator's parts, one concern per module, joined by codegen.Gen over one output buffer:

base          C spelling helpers (cid, c_string, c_compare) and the shared output state
types         C types of ST types
declarations  POU structs, FUNCTION prototypes, globals, the assertion site table
init          default and declared initial values, each POU's init function
statements    POU bodies and FUNCTIONs, one `s_<Kind>` per statement kind
expressions   one `x_<Kind>` per expression kind
calls         user functions, conversions, standard functions (their emitters are in stdfuncs.py)
config        the configuration's init/run, variable and located tables, test entry points
"""
