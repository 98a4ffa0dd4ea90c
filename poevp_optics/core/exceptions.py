"""The one base class of errors caused by what the user gave (files, keys, flags, folders).

The command line prints such an error as one line (`poevp: error: <message>`) and exits 2; the
message names the file and the key (or the flag) and the allowed range. Anything else that
escapes a command is also one line (core/failures.py: exit 2 for a path the OS refuses, 1 for
the environment or a bug); `--debug` or POEVP_DEBUG=1 keeps its traceback.
"""

from __future__ import annotations


class UserError(ValueError):
    """Bad input: the message is one line naming the file and key (or flag) at fault."""

    def __init__(self, message: str):
        # one line, whatever the cause's text held (Mitsuba and OS messages can be multi-line)
        super().__init__(" ".join(str(message).split()))


class ParamError(UserError):
    """A bad parameter value: the message names the dotted key (and the file it came from)."""


class SceneError(ParamError):
    """Invalid scene file or override; the message names the file and the key."""
