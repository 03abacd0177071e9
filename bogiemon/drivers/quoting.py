"""Text from a file, as a message quotes it: on one line, with nothing a terminal would act on.

A header, a value or a name read from a file may hold a newline (a message then seems to say two
things), a terminal's escape sequence (ESC [ 2 J clears the screen of whoever reads the journal),
or megabytes. Every message that quotes such text quotes it through quoted(): the characters that
do not print (controls, escapes, line and paragraph separators) written as Python writes them in a
string (\\n, \\x1b, \\u2028), bytes that are not UTF-8 as \\xNN, and the whole cut to a limit.
"""

from __future__ import annotations

QUOTE_LIMIT = 60  # characters of quoted text, by default: enough to recognise a header or a value


def quoted(text: str | bytes, limit: int = QUOTE_LIMIT) -> str:
    """text escaped onto one line and cut to `limit` characters ('...' marks a cut)."""
    if isinstance(text, bytes):
        text = text.decode("utf-8", errors="backslashreplace")
    shown = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text[: limit + 1])
    return shown if len(shown) <= limit and len(text) <= limit else shown[: max(0, limit - 3)] + "..."


def printable(message: str) -> str:
    """A message with its own line breaks kept and every other character that does not print
    escaped: the last guard of what reaches a terminal (cli/main.py prints errors through it)."""
    return "\n".join("".join(c if c.isprintable() or c == "\t" else repr(c)[1:-1] for c in line) for line in message.split("\n"))
