import torch

from lumos3d_cli.model.layers.rope import RotaryTables, patch_positions


def test_positions_are_row_major_from_one_after_the_special_tokens():
    positions = patch_positions(2, 3, num_special=2)
    assert positions.tolist() == [[0, 0], [0, 0], [1, 1], [1, 2], [1, 3], [2, 1], [2, 2], [2, 3]]


def test_position_zero_is_the_identity_and_norms_are_kept():
    positions = torch.tensor([[0, 0], [3, 7], [12, 1]])
    tables = RotaryTables.build(positions, head_dim=16, frequency=100.0, max_position=13)
    x = torch.randn(2, 4, 3, 16)
    rotated = tables.apply(x)
    torch.testing.assert_close(rotated[:, :, 0], x[:, :, 0])
    torch.testing.assert_close(rotated.norm(dim=-1), x.norm(dim=-1))


def test_attention_scores_depend_only_on_relative_position():
    torch.manual_seed(0)
    q, k = torch.randn(1, 1, 1, 32), torch.randn(1, 1, 1, 32)

    def score(p: tuple[int, int], r: tuple[int, int]) -> torch.Tensor:
        tables = RotaryTables.build(torch.tensor([p, r]), head_dim=32, frequency=100.0, max_position=16)
        rotated_q = tables.apply(torch.cat((q, k), dim=2))[:, :, 0]
        rotated_k = tables.apply(torch.cat((q, k), dim=2))[:, :, 1]
        return (rotated_q * rotated_k).sum()

    torch.testing.assert_close(score((2, 3), (5, 1)), score((12, 8), (15, 6)))
    assert not torch.allclose(score((2, 3), (5, 1)), score((2, 3), (5, 2)))


def test_first_half_rotates_with_rows_and_pairs_i_with_i_plus_quarter():
    head_dim, frequency = 8, 100.0
    tables = RotaryTables.build(torch.tensor([[1, 0]]), head_dim, frequency, max_position=2)  # row 1, column 0
    x = torch.zeros(1, 1, 1, head_dim)
    x[..., 0] = 1.0  # row half, pair (0, 2), lowest frequency index: angle = 1 * 100^0 = 1 rad
    rotated = tables.apply(x)[0, 0, 0]
    expected = torch.zeros(head_dim)
    expected[0], expected[2] = torch.cos(torch.tensor(1.0)), torch.sin(torch.tensor(1.0))
    torch.testing.assert_close(rotated, expected)
    x = torch.zeros(1, 1, 1, head_dim)
    x[..., 5] = 1.0  # column half: column 0 means no rotation
    torch.testing.assert_close(tables.apply(x), x)
