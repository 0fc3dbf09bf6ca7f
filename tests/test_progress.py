import io

from qpatrol.progress import Bar


class Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_bar_draws_on_a_terminal_only():
    piped = io.StringIO()
    bar = Bar("train", stream=piped)
    bar(5, 10)
    bar(10, 10)
    bar.close()
    assert piped.getvalue() == ""
    tty = Tty()
    bar = Bar("train", stream=tty)
    bar(10, 10)
    bar.close()
    out = tty.getvalue()
    assert "train" in out and "10/10 steps" in out and out.endswith("\n")
