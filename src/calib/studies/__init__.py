"""The studies: what turns config sections, paths and seeds into tables, figures and proofs (one module per
workflow stage family). The only code that knows config keys and output paths; called by the workflow scripts
and the command line."""
