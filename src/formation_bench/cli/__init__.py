"""The ``formation-bench`` command line: :mod:`.main` (``run``, ``reproduce``, ``score``, ...)
and :mod:`.sweep_commands` (``sweep`` and ``report``).

Kept empty: the command's entry point imports :mod:`.command_start` before anything heavy.
"""
