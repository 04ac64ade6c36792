"""pytest setup for the notebook tests (nbmake runs each notebook with nbclient inside this process).

Why the notebook tests once sat idle for 612 s (issue 9), and what this file does about it.

nbclient sends a cell's ``execute_request`` on an asyncio ZeroMQ socket and then
waits on that socket with ``poll(timeout)`` for the reply. ZeroMQ signals
readiness on an *edge-triggered* file descriptor; when the machine is busy
(the kernel trains a model on both cores while nbclient's event loop waits its
turn) the edge that should hand the queued request to the kernel can be
consumed without anyone acting on it. Nothing else touches the socket, so the
request sits in the client until ``poll`` gives up at the cell timeout and
re-reads the socket's state: then the message goes out, the kernel runs the
cell in milliseconds, and the test passes, after waiting the whole timeout
(nbmake's default was 600 s: hence the 612 s idle, with the kernel idle in its
event loop all along). A reproduction script (``benchmarks/repro_kernel_hang.py``, now in git history) showed it:
with both cores busy, one run of 150 cells took 364 s (six stalls of exactly
the 60 s timeout); with the slices below, 5 runs took 4-8 s, the longest stall 1 s.
(ipykernel 7.0-7.3 had the same lost wake-up on the kernel's side of the socket,
fixed in 7.4, which pyproject.toml asks for.)

The fix for our tests: poll in slices of at most a second. Each new ``poll``
re-reads the socket's state, so a lost wake-up costs at most a second instead
of the whole timeout; the overall timeout and the messages are unchanged.
"""
from __future__ import annotations

import time
from queue import Empty

SLICE_S = 1.0


def slice_kernel_polls(slice_s: float = SLICE_S) -> None:
    """Make jupyter_client's async ``get_msg(timeout)`` poll in slices of ``slice_s`` seconds (same overall timeout)."""
    from jupyter_client.channels import AsyncZMQSocketChannel

    if getattr(AsyncZMQSocketChannel.get_msg, "_sliced", False):
        return

    async def get_msg(self, timeout: float | None = None):
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            wait = slice_s if deadline is None else min(slice_s, deadline - time.monotonic())
            if wait <= 0:
                raise Empty
            if await self.socket.poll(int(wait * 1000)):
                return await self._recv()

    get_msg._sliced = True
    AsyncZMQSocketChannel.get_msg = get_msg


slice_kernel_polls()
