"""Exit codes of the ``rigcal`` command (light: imported before any command runs).

0 calibrated and consistent; 1 error (bad input, or the data cannot determine the result);
2 command-line usage; 3 flagged; 4 partial; 6 moved (``rigcal check`` / ``diff``: a sensor moved);
7 cannot tell (``check`` / ``diff``: no sensor moved, but some could not be told); 130 interrupted
(Ctrl-C); 143 terminated (SIGTERM).
"""

from __future__ import annotations

#: exit code of a result the consistency check flagged
EXIT_FLAGGED = 3
#: exit code of a partial result: some sensors calibrated (and written), others not (rigcal mocap)
EXIT_PARTIAL = 4
#: exit code of ``rigcal check`` / ``rigcal diff`` when a sensor moved (the calibration is stale)
EXIT_MOVED = 6
#: exit code of ``rigcal check`` / ``rigcal diff`` when no sensor moved but some cannot be told
#: (too few boards, no shared board, a sensor missing from the data)
EXIT_CANNOT_TELL = 7
EXIT_INTERRUPTED = 130  # Ctrl-C (128 + SIGINT)
EXIT_TERMINATED = 143  # SIGTERM (128 + SIGTERM)

#: the exit codes as the top-level ``rigcal --help`` lists them
EXIT_CODES_HELP = f"""exit codes:
  0    calibrated (or written) and consistent
  1    error: bad input, or the data cannot determine the result (one line on stderr)
  2    command-line usage
  {EXIT_FLAGGED}    flagged: the result contradicts its own noise model (nothing written unless --force)
  {EXIT_PARTIAL}    partial (rigcal mocap): the other sensors calibrated and written, some not
  {EXIT_MOVED}    moved (rigcal check / diff): a sensor moved since it was calibrated
  {EXIT_CANNOT_TELL}    cannot tell (rigcal check / diff): nothing moved, but some sensor could not be told
  {EXIT_INTERRUPTED}  interrupted (Ctrl-C); nothing half-written is left
  {EXIT_TERMINATED}  terminated (SIGTERM); nothing half-written is left
"""


class Terminated(BaseException):
    """Raised in the main thread when the process receives SIGTERM (see :func:`rigcal.cli.main.entry`)."""
