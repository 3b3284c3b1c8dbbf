"""The terminal layer: Typer commands that parse options, call the library and render output."""
