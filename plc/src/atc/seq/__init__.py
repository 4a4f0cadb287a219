"""Tool-change sequences (Logosol "Tools Sequences", docs/logosol.md): parse, check, compile into ST step tables.

Stages, each a module with one input and one output:
    lexer -> parser (model) -> checker (in the context of index) -> assemble -> stgen
cli.main(argv) implements `plc seq check` and `plc seq compile`; encoding is the contract with the ST runner.
"""
