"""notebooks/conftest.py: the notebook runner polls its kernel in short slices (the stall of issue 9)."""

import asyncio
import importlib.util
from pathlib import Path
from queue import Empty

import pytest
from jupyter_client.channels import AsyncZMQSocketChannel

spec = importlib.util.spec_from_file_location("nb_conftest", Path(__file__).parents[1] / "notebooks" / "conftest.py")
nb_conftest = importlib.util.module_from_spec(spec)
spec.loader.exec_module(nb_conftest)  # patches AsyncZMQSocketChannel.get_msg, as it does under nbmake


class FakeSocket:
    """Answers ``poll`` with ``ready`` after ``misses`` empty polls; records each poll's timeout (ms)."""

    def __init__(self, misses: int):
        self.misses, self.timeouts = misses, []

    async def poll(self, timeout_ms):
        self.timeouts.append(timeout_ms)
        return 0 if len(self.timeouts) <= self.misses else 1


class FakeChannel:
    def __init__(self, misses):
        self.socket = FakeSocket(misses)

    async def _recv(self):
        return {"msg": "reply"}


def get_msg(channel, timeout):
    return asyncio.run(AsyncZMQSocketChannel.get_msg(channel, timeout))


def test_polls_in_slices_of_a_second_until_the_message_comes():
    ch = FakeChannel(misses=3)
    assert get_msg(ch, timeout=None) == {"msg": "reply"}
    assert ch.socket.timeouts == [1000, 1000, 1000, 1000]  # a lost wake-up costs a second, not the whole timeout


def test_keeps_the_overall_timeout():
    ch = FakeChannel(misses=10**6)
    with pytest.raises(Empty):
        get_msg(ch, timeout=0.05)
    assert ch.socket.timeouts and all(t <= 50 for t in ch.socket.timeouts)


def test_patching_twice_keeps_one_layer():
    patched = AsyncZMQSocketChannel.get_msg
    nb_conftest.slice_kernel_polls()
    assert AsyncZMQSocketChannel.get_msg is patched and patched._sliced
