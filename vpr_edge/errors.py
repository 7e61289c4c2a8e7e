"""User-facing problems: the exception the CLI turns into one line, and warnings said once each.

A library function names its inputs as the library knows them (``BuildOptions.positions_topic``, an argument
``topic``), never as one command line spells them: a ``Message`` writes each input ``{opt.NAME}`` and is
rendered with the names in force (``input_names``; the library's own by default, the CLI's option flags
while one of its commands runs). ``InputError`` is the error that says which inputs are wrong.
"""
from __future__ import annotations

import contextlib
import string
import sys
from collections.abc import Callable, Iterator, Sequence

_said: set[str] = set()
_naming: list[Callable[[str], str]] = [lambda name: name]   # the names in force: the last one


class VprError(Exception):
    """A user-facing error: bad input file, mismatched map, missing dependency. Message is one line."""


class _Names:
    """``{opt.NAME}`` in a template: NAME as ``name_of`` gives it."""

    def __init__(self, name_of: Callable[[str], str]) -> None:
        self._name_of = name_of

    def __getattr__(self, name: str) -> str:
        return self._name_of(name)


class Message:
    """A line that names a library call's inputs: ``template`` writes each input ``{opt.NAME}`` (NAME: the
    library's name for it, e.g. ``positions_topic``) and each value ``{key}`` (``values``: anything ``format``
    takes, or a ``Message``, rendered with the same names). ``str`` renders it with the names in force."""

    def __init__(self, template: str, **values: object) -> None:
        self.template, self.values = template, values

    @property
    def inputs(self) -> tuple[str, ...]:
        """The inputs it names, in order, each once (those of ``Message`` values included)."""
        names = [field[4:] for _, field, _, _ in string.Formatter().parse(self.template)
                 if field and field.startswith("opt.")]
        names += [n for v in self.values.values() if isinstance(v, Message) for n in v.inputs]
        return tuple(dict.fromkeys(names))

    def line(self, name_of: Callable[[str], str]) -> str:
        """The text, each input named by ``name_of`` (the library's name -> the caller's)."""
        values = {k: v.line(name_of) if isinstance(v, Message) else v for k, v in self.values.items()}
        return self.template.format(opt=_Names(name_of), **values)

    def __str__(self) -> str:
        return self.line(_naming[-1])

    @classmethod
    def join(cls, parts: Sequence["Message | str"], sep: str = ", ") -> "Message":
        """``parts`` one after another, ``sep`` between (plain text taken as it is)."""
        escaped = sep.replace("{", "{{").replace("}", "}}")
        return cls(escaped.join(f"{{p{i}}}" for i in range(len(parts))), **{f"p{i}": p for i, p in enumerate(parts)})


def said(template: str, **values: object) -> str:
    """``Message(template, **values)`` rendered now, with the names in force (for a warning or a label)."""
    return str(Message(template, **values))


class InputError(VprError):
    """Inputs that are wrong (they contradict each other, or the files they name): ``inputs`` names them as
    the library does; the line (``Message``) names them as the caller does once rendered (``str``: the names
    in force; ``line(name_of)``: given names), so that the CLI says ``--positions`` where a library caller
    reads ``positions``."""

    def __init__(self, template: "str | Message", **values: object) -> None:
        self.message = template if isinstance(template, Message) else Message(template, **values)
        super().__init__(self.message.template)

    @property
    def inputs(self) -> tuple[str, ...]:
        return self.message.inputs

    def line(self, name_of: Callable[[str], str]) -> str:
        return self.message.line(name_of)

    def __str__(self) -> str:
        return str(self.message)

    def __reduce__(self):   # pickled whole (a Ray worker's error), not rebuilt from args alone
        return (type(self), (self.message,))


@contextlib.contextmanager
def input_names(name_of: Callable[[str], str]) -> Iterator[None]:
    """Render every ``Message`` (errors, warnings) with ``name_of`` while the block runs: how a command line
    puts its option flags where the library names its inputs."""
    _naming.append(name_of)
    try:
        yield
    finally:
        _naming.remove(name_of)


class MapChanged(VprError):
    """The map file a running command reads was rewritten in place (``cp new.npz route.npz``): its
    memory-mapped rows are no longer the map that was opened. The command stops, keeping what it wrote."""


class Terminated(BaseException):
    """SIGTERM (how systemd and container runtimes stop a service), raised where the process is, so that
    every ``finally`` and ``except BaseException`` runs: temporary files are removed, nothing is half
    written. Exit code 143 (128 + 15), as the shell reports a process ended by SIGTERM."""

    exit_code = 143


def terminate_cleanly() -> None:
    """From now on, SIGTERM raises ``Terminated`` in the main thread instead of killing the process."""
    import signal

    def handler(signum, frame) -> None:
        raise Terminated()

    signal.signal(signal.SIGTERM, handler)


@contextlib.contextmanager
def held_signals() -> Iterator[None]:
    """Hold Ctrl-C (SIGINT) and SIGTERM while the block runs, so that what it does (a result line written and
    counted) is done whole; one that came meanwhile acts when the block ends, as it would have. In the main
    thread, where Python handles signals; elsewhere the block runs as it is."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    came: list[int] = []
    held = (signal.SIGINT, signal.SIGTERM)
    before = {s: signal.getsignal(s) for s in held}
    if any(h is None for h in before.values()):   # a handler not set from Python cannot be put back
        yield
        return
    for s in held:
        signal.signal(s, lambda signum, frame: came.append(signum))
    try:
        yield
    finally:
        for s, handler in before.items():
            signal.signal(s, handler)
        if came:
            signal.raise_signal(came[0])


def printable(text: str) -> str:
    """``text`` with the bytes of a file name that is not UTF-8 (held as lone surrogates, Python's
    ``surrogateescape``) written ``\\xNN``, as Git quotes such names: every message and output line can be
    written, and says which bytes the name has."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def warn(message: "str | Message") -> None:
    """Print ``vpr-edge: warning: message`` on stderr, once per distinct message in this process (a
    ``Message`` rendered with the names in force)."""
    message = str(message)
    if message not in _said:
        _said.add(message)
        print(f"vpr-edge: warning: {printable(message)}", file=sys.stderr, flush=True)


def os_error_line(e: OSError) -> str:
    """A file the system refused (disk full, permission): ``file: reason``, or the reason alone."""
    return f"{e.filename}: {e.strerror or e}" if e.filename else str(e.strerror or e)


def ctrl_c(e: BaseException) -> BaseException:
    """``e`` as it should be handled: a SystemError that a C extension (NumPy's file read, ...) raised because
    Ctrl-C came while it ran is the KeyboardInterrupt that caused it; anything else is itself."""
    if isinstance(e, SystemError) and isinstance(e.__cause__ or e.__context__, KeyboardInterrupt):
        return e.__cause__ or e.__context__   # type: ignore[return-value]
    return e


def one_line_errors(prog: str, main: Callable[[], int]) -> int:
    """Run a command-line ``main``; a VprError, or a file the system refuses (OSError), becomes
    ``prog: error: message`` on stderr and exit code 2 instead of a traceback (for the tools run by
    ``python``; the ``vpr-edge`` CLI does the same through typer). SIGTERM and Ctrl-C end it cleanly (143 / 130)."""
    terminate_cleanly()
    try:
        try:
            return main()
        except SystemError as e:   # Ctrl-C inside a C extension: Ctrl-C
            if ctrl_c(e) is e:
                raise
            raise ctrl_c(e) from None
    except Terminated:
        print(f"{prog}: terminated", file=sys.stderr)
        return Terminated.exit_code
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except VprError as e:
        print(f"{prog}: error: {printable(str(e))}", file=sys.stderr)
    except OSError as e:
        print(f"{prog}: error: {printable(os_error_line(e))}", file=sys.stderr)
    return 2
