"""Assertions shared by the command-line tests."""


def expect_input_error(result, *fragments: str) -> None:
    """The CLI refused bad input the standard way: exit code 2, a one-line `error:` message
    holding every fragment, no traceback."""
    assert result.code == 2, (result.code, result.err)
    assert result.err.strip().splitlines()[-1].startswith("error:"), result.err
    assert not result.err.startswith("\n") and "\n\n" not in result.err, repr(result.err)  # no empty progress display
    for fragment in fragments:
        assert fragment in result.err, result.err
    assert "Traceback" not in result.err
