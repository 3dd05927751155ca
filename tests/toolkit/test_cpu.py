"""Process-wide CPU settings scoped to a block: deterministic kernels (issue 18, case 3)."""

import pytest

torch = pytest.importorskip("torch")

from trioman.toolkit.cpu import deterministic_kernels  # noqa: E402


def laplacian_grad(values: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
    """The avatar's Laplacian regulariser's gradient: the backward of an index with repeated entries."""
    values.grad = None
    (values - values[neighbours].mean(1)).square().sum().backward()
    return values.grad.clone()


def test_deterministic_kernels_repeat_the_index_backward_bit_for_bit_and_restore_the_setting():
    # Without them, two threads accumulate the repeated entries in a varying order (measured: up to ~1e-6 apart).
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        gen = torch.Generator().manual_seed(0)
        values = torch.randn(20000, 3, generator=gen, requires_grad=True)
        neighbours = torch.randint(0, 20000, (20000, 6), generator=gen)
        assert not torch.are_deterministic_algorithms_enabled()
        with deterministic_kernels():
            assert torch.are_deterministic_algorithms_enabled()
            first = laplacian_grad(values, neighbours)
            for _ in range(10):
                assert torch.equal(laplacian_grad(values, neighbours), first)
        assert not torch.are_deterministic_algorithms_enabled()
        assert torch.utils.deterministic.fill_uninitialized_memory  # torch's default, back
    finally:
        torch.set_num_threads(threads)
