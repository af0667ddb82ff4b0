"""`pure-hil`'s commands, one module each: `add_arguments(parser)` beside `handle(args) -> int`, and
`common.py`, what they share. hil/cli.py's table names them; a command's module is imported only when that
command runs."""
