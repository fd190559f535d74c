"""Loading torch files without running their code, unless the user says they trust them.

A pickled torch file (``torch.save`` of a whole module, or of any Python object) runs code while it
is unpickled: a crafted ``.pt`` can do anything the user can. So every torch file the project reads
goes through :func:`torch_load`, which uses ``torch.load(weights_only=True)`` (tensors, plain
containers and numbers only). A file that needs more is refused with one line naming what it would
import, unless the user passed ``--trust-model`` on the command line: the CLI (and only the CLI)
enters :func:`trusted_models` for the command's duration. The trust is a process-scoped setting
rather than a config field on purpose: a recipe, a ``--set`` override or a stored config can never
turn it on. TorchScript archives (``torch.jit.load``) hold no pickled Python code and load
without it.
"""
from __future__ import annotations

import contextlib
import contextvars
import os
from typing import Any, Iterator

from staticdepth.errors import InputError

_TRUSTED: contextvars.ContextVar[bool] = contextvars.ContextVar("staticdepth_trust_model",
                                                               default=False)

TRUST_HINT = "pass --trust-model on the command line only if you trust the file's source"


def models_trusted() -> bool:
    """True inside :func:`trusted_models` (the user passed ``--trust-model``)."""
    return _TRUSTED.get()


@contextlib.contextmanager
def trusted_models(trust: bool = True) -> Iterator[None]:
    """Allow pickled torch files for the block when ``trust``; ``False`` never revokes an outer
    trust (a recipe's stages run inside ``run --trust-model`` keep it)."""
    token = _TRUSTED.set(True) if trust else None
    try:
        yield
    finally:
        if token is not None:
            _TRUSTED.reset(token)


def torch_load(path: str | os.PathLike, *, what: str = "torch file") -> Any:
    """``torch.load`` on the CPU with ``weights_only=True``; a file whose unpickling would import
    other Python objects is refused (:class:`InputError` naming them) unless trusted."""
    import pickle
    import re

    import torch

    path = os.fspath(path)
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        refusal = str(e)  # a corrupt file or one needing more than tensors: told apart below
    except OSError:
        raise
    except Exception as e:  # torch raises many types for a corrupt file
        raise InputError(f"not a readable {what} ({type(e).__name__}: {_first_line(e)})",
                         path) from None
    try:  # scans the pickle's opcodes; nothing is executed
        unsafe = torch.serialization.get_unsafe_globals_in_checkpoint(path)
    except Exception:  # the legacy (non-zip) format: torch's refusal names the first global
        unsafe = re.findall(r"Unsupported global: GLOBAL (\S+)", refusal)
    if not unsafe:
        raise InputError(f"not a readable {what} (corrupt pickle)", path)
    if not models_trusted():
        shown = ", ".join(unsafe[:3]) + (", ..." if len(unsafe) > 3 else "")
        raise InputError(f"loading this {what} would run code (it imports {shown}); refused: "
                         f"{TRUST_HINT}", path)
    try:
        return torch.load(path, map_location="cpu", weights_only=False)
    except Exception as e:
        raise InputError(f"not a readable {what} ({type(e).__name__}: {_first_line(e)})",
                         path) from None


def _first_line(e: BaseException) -> str:
    return (str(e).strip().splitlines() or [""])[0][:200]
