"""A Ctrl-C is the user's, wherever it lands.

One that comes while a compiled (numba) loop runs surfaces as a SystemError ("returned a result with an
exception set") caused by the KeyboardInterrupt; a run or an agent that reports any failure as its outcome
must raise it again as the Ctrl-C it is.
"""

from __future__ import annotations


def reraise_ctrl_c(error: BaseException) -> None:
    """Raise the KeyboardInterrupt behind ``error`` (its cause or context, at any depth), if there is one."""
    cause, seen = error, set()
    while cause is not None and id(cause) not in seen:  # a chain may loop
        if isinstance(cause, KeyboardInterrupt):
            raise cause
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
