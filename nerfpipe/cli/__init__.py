"""The `nerfpipe` command line: a thin typer layer over ``nerfpipe.pipeline``."""
