"""Command-line interface (click). Thin: each command parses, calls one library function, prints."""
