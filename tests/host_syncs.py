"""Counting, on the CPU, the operations that would make a GPU wait for the host, and those that
would run in float64 on it.

On a GPU the host queues kernels ahead of the device; an operation whose result the host must
read (a tensor turned into a Python number or list, an output whose size depends on the data,
like ``nonzero`` or a boolean index) stops the queue until the device catches up. On a CPU those
operations cost nothing extra, so a hot path can gain one unnoticed: :func:`host_syncs` finds them
anyway, from the operations themselves, and says where each was called from.

Two layers see them: a ``TorchDispatchMode`` sees the aten operations (including those autograd
runs in the backward pass), a ``TorchFunctionMode`` the Python-level conversions that never reach
the dispatcher (``tolist``, ``numpy``). See PyTorch's ``torch.utils._python_dispatch`` and
``torch.overrides`` documentation, and the CUDA semantics notes on asynchronous execution.

:func:`float64_ops` finds, the same way, the operations that take or give a float64 tensor: a GPU
runs float64 at a fraction of its float32 rate (a 64th on consumer cards, NVIDIA's CUDA C
Programming Guide, "Arithmetic Instructions"), so a training step keeps to float32 and below.
"""

from __future__ import annotations

import contextlib
import traceback
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import torch
import torch.utils._pytree as pytree
from torch.overrides import TorchFunctionMode
from torch.utils._python_dispatch import TorchDispatchMode

PROJECT = Path(__file__).resolve().parents[1]
OWN_CODE = tuple(str(PROJECT / package) for package in ("m2d2m", "training", "orchestration", "pipelines"))
_NOT_CALLERS = (str(Path(torch.__file__).parent), __file__)

# aten operations whose result the host must read, or whose output size depends on the data
_SYNCING_OPS = {
    "aten::_local_scalar_dense",  # .item(), bool(t), int(t), float(t)
    "aten::nonzero",
    "aten::masked_select",
    "aten::unique_consecutive",
    "aten::_unique",
    "aten::_unique2",
    "aten::unique_dim",
    "aten::equal",
    "aten::is_nonzero",
    "aten::bincount",
    "aten::argwhere",
}
# Python-level conversions that read the tensor on the host without an aten operation
_SYNCING_METHODS = {torch.Tensor.tolist, torch.Tensor.numpy}


@dataclass
class FoundOps:
    """What one :func:`host_syncs` or :func:`float64_ops` block found: each operation with the place
    in the project's own code (file:line) that led to it."""

    calls: list[tuple[str, str]] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.calls)

    def by_place(self) -> Counter[tuple[str, str]]:
        return Counter(self.calls)

    def report(self) -> str:
        """One line per (operation, place), most frequent first: the failure message of a test."""
        return "\n".join(f"{n:4d} × {op} at {place}" for (op, place), n in self.by_place().most_common())


def _caller() -> str:
    """The innermost frame of the project's own code on the stack (file:line), else the innermost
    frame outside torch and this file (a test's, a library's)."""
    frames = [f for f in traceback.extract_stack() if not f.filename.startswith(_NOT_CALLERS)]
    for frame in reversed(frames):
        if frame.filename.startswith(OWN_CODE):
            return f"{Path(frame.filename).relative_to(PROJECT)}:{frame.lineno}"
    return f"{frames[-1].filename}:{frames[-1].lineno}" if frames else "?"


def _is_boolean_index(func: torch._ops.OpOverload, args: tuple) -> bool:
    """``x[mask]`` and ``x[mask] = v``: aten.index / index_put with a boolean index, which the
    kernel turns into positions with a nonzero the dispatcher never shows."""
    if func.overloadpacket not in (torch.ops.aten.index, torch.ops.aten.index_put, torch.ops.aten.index_put_):
        return False
    indices = args[1] if len(args) > 1 else ()
    return any(isinstance(i, torch.Tensor) and i.dtype in (torch.bool, torch.uint8) for i in indices or ())


def _is_sized_by_data(func: torch._ops.OpOverload, kwargs: dict) -> bool:
    """``repeat_interleave`` with a tensor of repeats and no ``output_size``: sized by the data."""
    return func.overloadpacket is torch.ops.aten.repeat_interleave and kwargs.get("output_size") is None


class _Watching(TorchDispatchMode):
    """A dispatch mode that records what it finds into ``found``."""

    def __init__(self, found: FoundOps) -> None:
        super().__init__()
        self.found = found


class _DispatchCounter(_Watching):
    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        name = func._schema.name
        if name in _SYNCING_OPS or _is_boolean_index(func, args) or _is_sized_by_data(func, kwargs):
            self.found.calls.append((name if name in _SYNCING_OPS else f"{name} (data-sized)", _caller()))
        return func(*args, **kwargs)


class _FunctionCounter(TorchFunctionMode):
    def __init__(self, found: FoundOps) -> None:
        super().__init__()
        self.found = found

    def __torch_function__(self, func, types, args=(), kwargs=None):
        if func in _SYNCING_METHODS:
            self.found.calls.append((f"Tensor.{func.__name__}", _caller()))
        return func(*args, **(kwargs or {}))


@contextlib.contextmanager
def host_syncs() -> Iterator[FoundOps]:
    """Count the host syncs of the block: ``with host_syncs() as found: step()``, then
    ``assert not found, found.report()``."""
    found = FoundOps()
    with _FunctionCounter(found), _DispatchCounter(found):
        yield found


class _Float64Counter(_Watching):
    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        result = func(*args, **kwargs)
        tensors = (x for x in pytree.tree_leaves((args, kwargs, result)) if isinstance(x, torch.Tensor))
        if any(tensor.dtype in (torch.float64, torch.complex128) for tensor in tensors):
            self.found.calls.append((func._schema.name, _caller()))
        return result


@contextlib.contextmanager
def float64_ops() -> Iterator[FoundOps]:
    """The operations of the block that take or give a float64 tensor, forward and backward:
    ``with float64_ops() as found: step()``, then ``assert not found, found.report()``."""
    found = FoundOps()
    with _Float64Counter(found):
        yield found
