"""The exit status of every ``fixstream`` command (docs/clients.md lists which command returns which).

* ``OK`` (0): done.
* ``FAILURE`` (1): the command ran but did not succeed: a replay interrupted before its end, a scenario file that
  does not validate (``scenarios validate``), a stack whose driver failed (``up``).
* ``USAGE`` (2): bad usage or bad input: an unknown option or value (argparse), a file that cannot be read, a bad
  key expression, an unreachable router or an invalid setting (one line on stderr, never a traceback).
* ``TIMEOUT`` (3): what the command waited for did not come in time: the services a play waits for, the
  ``--count`` messages of ``echo`` within ``--timeout``, any message at all for ``topics`` and ``hz``, any answer
  for ``status``.
* ``INTERRUPTED`` (130): Ctrl-C before a command had set up its own handling, also while it waits for its router
  (the shell's convention, 128 + SIGINT); 143: SIGTERM in that same wait (128 + SIGTERM).
  Commands that run until stopped (``echo``, ``hz``, ``foxglove``, ``record``, ``router``, ``run``) end normally on
  Ctrl-C or SIGTERM.
"""

from __future__ import annotations

OK = 0
FAILURE = 1
USAGE = 2
TIMEOUT = 3
INTERRUPTED = 130

#: the table ``fixstream --help`` ends with
EPILOG = (
    "exit status: 0 ok; 1 failure (e.g. a replay interrupted, an invalid scenario file); 2 usage or bad input (an"
    " unknown option, an unreadable file, an unreachable router); 3 timeout (what the command waited for did not come:"
    " services to wait for, echo --count messages, any message for topics/hz, any status answer); 130 Ctrl-C (143"
    " SIGTERM) during start-up."
)
