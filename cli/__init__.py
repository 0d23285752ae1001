"""The ``metro`` command line (typer). Thin: parse, call one library function, print or write."""
