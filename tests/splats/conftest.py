"""Splat tests run torch on one thread.

Their renders are tiny and gain nothing from more threads, while on a busy CI machine an
oversubscribed thread pool makes them many times slower. The setting is restored afterwards.
"""

import pytest
import torch


@pytest.fixture(autouse=True)
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
