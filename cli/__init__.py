"""The ``awr`` command-line front end (installed as ``awr_denoise.cli``).

Thin by design: argument parsing, progress and exit statuses around library calls. The
entry point is :func:`awr_denoise.cli.main.main`.
"""

__all__: list[str] = []
