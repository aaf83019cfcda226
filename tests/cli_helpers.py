"""What tests of the `gonio` command share."""


def one_clear_line(capsys, *needles):
    """The captured stderr is one line, no traceback, holding each of ``needles``; returned."""
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    for n in needles:
        assert n in err, err
    return err
