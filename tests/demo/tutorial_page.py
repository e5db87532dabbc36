"""Run docs/tutorial.md as a script: its command blocks in order, with real processes.

The page's conventions (written for readers first; the runner reads the same text):

- A ```bash block is commands that run, each block in a fresh ``bash -e`` in one working
  directory (the reader's checkout: here a temporary directory with ``demo`` and a ``.venv``).
- A ```console block is what the ```bash block before it prints. Every non-blank line of it
  must be found, in order, in what the command really printed, with each number standing for
  any number (``7447`` for the test's port, a pose for the pose of this run) and ``...`` for
  anything. So the wording and the shape of the sample output are checked, not the digits.
- A ```sh block is shown and not run (it needs tools that are not here, ROS 2): its fleetsim
  commands are checked by their own argument parsers.
- A ```python or ```yaml block that follows ``<!-- tutorial: file NAME -->`` is a file the
  reader saves as NAME: the runner writes it.
- An HTML comment ``<!-- tutorial: KIND [ARGS] -->`` (invisible on the rendered page) tells
  the runner what a reader does besides typing into a shell:

  ``background NAME``   the next ```bash block runs in a terminal of its own and keeps running
                        (its ```console block, if any, is waited for);
  ``tmux NAME [keys=K] [exact=TEXT]``  the next ```bash block runs in a real terminal (tmux),
                        one line a terminal (NAME, NAME2, ...), each a teleop (waited for until
                        it says ``[robot alive]``); K are keys typed into each
                        (``w*15 a*3``); every screen must come to show TEXT as it is, and the
                        first the ```console block after it;
  ``keys NAME K``       type K into terminal NAME (and NAME2, ...);
  ``stop NAME``         Ctrl-C in terminal NAME: it must end with status 0;
  ``wait NAME``         terminal NAME's command ends by itself, with status 0 (and has printed
                        the ```console block after the directive, if any, its lines in any
                        order: things end in the order they end);
  ``browser NAME JS [picture=FILE]``  open the URL that NAME printed in headless Chromium and
                        wait until JS is true (the page's ``viewerStats``); FILE names the
                        screenshot when pictures are asked for (scripts/tutorial_pictures.py);
  ``picture PATH FILE`` PATH, a picture a command wrote, becomes FILE;
  ``bounded FROM TO``   the next command runs with FROM replaced by TO: the bounded version of a
                        step that would take minutes of wall time (the only liberty taken);
  ``status N``          the next ```bash block ends with status N (default 0).

The fleetsim programs are reached as a reader reaches them after ``source .venv/bin/activate``,
through a ``.venv/bin`` whose programs are thin wrappers of the real ones adding ``-e``/``-l``
of a free loopback port (and ``--port`` for ``fleet-view``) unless the command gives them, so
the run never meets another daemon on 7447. ``FLEETSIM_ENDPOINT`` (which ``./demo`` honours)
names that port too.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from tests.cdp import Chromium
from tests.conftest import ROOT, free_port

PAGE = ROOT / "docs" / "tutorial.md"
VENV_BIN = Path(sys.executable).parent
TMUX = shutil.which("tmux")
CLIENTS = ("fleet", "fleet-spawn", "fleet-teleop", "fleet-map", "fleet-record")
PROGRAMS = ("simd", *CLIENTS, "fleet-view", "fleet-ros", "python", "python3")

_DIRECTIVE = re.compile(r"^<!--\s*tutorial:\s*(.*?)\s*-->\s*$")
_OPTION = re.compile(r"^[a-z]+=")
_FENCE = re.compile(r"^```(\w*)\s*$")
_NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?")


@dataclass
class Step:
    """One thing the reader does: a block to run, a file to save, or a directive alone."""

    kind: str  # run | background | tmux | file | keys | stop | wait | browser | picture | shown
    line: int  # where it is on the page (1-based)
    args: list[str] = field(default_factory=list)
    options: dict[str, str] = field(default_factory=dict)
    text: str = ""  # the block's text
    sample: str = ""  # the ```console block after a command block

    def where(self) -> str:
        return f"docs/tutorial.md:{self.line}"


def parse(text: str) -> list[Step]:
    """The page's steps in order (the conventions in this module's docstring)."""
    steps: list[Step] = []
    pending: list[Step] = []  # directives waiting for their block
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        if m := _DIRECTIVE.match(line):
            words = shlex.split(m.group(1))
            opts = dict(w.split("=", 1) for w in words[1:] if _OPTION.match(w))
            args = [w for w in words[1:] if not _OPTION.match(w)]
            d = Step(words[0], i + 1, args, opts)
            if d.kind in ("background", "tmux", "file", "bounded", "status"):
                pending.append(d)
            else:
                steps.append(d)
            i += 1
            continue
        if (m := _FENCE.match(line)) is None:
            i += 1
            continue
        lang, start = m.group(1), i + 1
        j = start
        while j < len(lines) and not lines[j].startswith("```"):
            j += 1
        body = "\n".join(lines[start:j])
        i = j + 1
        if lang == "console":
            if steps and steps[-1].kind in ("run", "background", "tmux", "wait") and not steps[-1].sample:
                steps[-1].sample = body
            continue
        if lang not in ("bash", "sh", "python", "yaml"):
            pending.clear()
            continue
        step = Step("run" if lang == "bash" else "shown", start, text=body)
        for d in pending:
            if d.kind in ("background", "tmux", "file"):
                step.kind, step.args = d.kind, d.args
                step.options.update(d.options)
            elif d.kind == "bounded":
                step.options.setdefault("bounded", "")
                step.options["bounded"] += f"{d.args[0]}\0{d.args[1]}\0"
            elif d.kind == "status":
                step.options["status"] = d.args[0]
        pending.clear()
        steps.append(step)
    return steps


def command_of(step: Step) -> str:
    """The block's commands as the run types them (with the bounded replacements)."""
    text = step.text
    subs = step.options.get("bounded", "").split("\0")
    for old, new in zip(subs[0:-1:2], subs[1:-1:2], strict=True):
        if old not in text:
            raise AssertionError(f"{step.where()}: 'bounded' names {old!r}, which the block does not hold")
        text = text.replace(old, new)
    return text


def sample_lines(sample: str) -> list[str]:
    """A console block's lines that are checked: not blank, not a lone ``...``."""
    return [line for line in sample.splitlines() if line.strip() and line.strip() != "..."]


def sample_pattern(line: str) -> re.Pattern[str]:
    """A sample line as a pattern: numbers match any number, ``...`` anything, runs of spaces any
    run of spaces."""
    parts = []
    for piece in re.split(r"(\.\.\.|\s+)", line.strip()):
        if piece == "...":
            parts.append(".*")
        elif piece.isspace():
            parts.append(r"\s+")
        else:
            pos = 0
            for n in _NUMBER.finditer(piece):
                parts += [re.escape(piece[pos : n.start()]), _NUMBER.pattern]
                pos = n.end()
            parts.append(re.escape(piece[pos:]))
    return re.compile("".join(parts))


def unmatched(sample: str, output: str, ordered: bool = True) -> str | None:
    """The first sample line not found, in order (or anywhere), in ``output`` (None when all are)."""
    lines = output.splitlines()
    k = 0
    for raw in sample_lines(sample):
        pat = sample_pattern(raw)
        if not ordered:
            k = 0
        while k < len(lines) and not pat.search(lines[k]):
            k += 1
        if k == len(lines):
            return raw
        k += 1
    return None


def wait_until(cond: Callable[[], bool], timeout: float, interval: float = 0.05) -> bool:
    deadline = time.monotonic() + timeout
    while True:
        if cond():
            return True
        if time.monotonic() > deadline:
            return False
        time.sleep(interval)


def _default_sigint() -> None:
    """A shell started in the background inherits SIGINT ignored; a terminal's job has the default."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def make_checkout(cwd: Path, endpoint: str, view_port: int) -> dict[str, str]:
    """``cwd`` as the reader's checkout: ``demo``, and a ``.venv/bin`` of wrappers (module
    docstring). Returns the environment the commands run in."""
    bin_dir = cwd / ".venv" / "bin"
    bin_dir.mkdir(parents=True)
    (cwd / "demo").symlink_to(ROOT / "demo")
    for prog in PROGRAMS:
        real = shlex.quote(str(VENV_BIN / prog))
        if prog == "simd":
            add = f'case " $* " in *" -l "*|*" --listen "*) ;; *) set -- "$@" -l {endpoint};; esac'
        elif prog in CLIENTS:
            add = f'case " $* " in *" -e "*|*" --connect "*) ;; *) set -- "$@" -e {endpoint};; esac'
        elif prog == "fleet-view":
            add = (
                f'case " $* " in *" -e "*) ;; *) set -- "$@" -e {endpoint};; esac\n'
                f'case " $* " in *" --port "*|*" --snapshot "*) ;; *) set -- "$@" --port {view_port};; esac'
            )
        else:
            add = ""
        script = bin_dir / prog
        script.write_text(f'#!/bin/bash\n{add}\nexec {real} "$@"\n')
        script.chmod(0o755)
    (bin_dir / "activate").write_text(
        f'export VIRTUAL_ENV={shlex.quote(str(cwd / ".venv"))}\nexport PATH="$VIRTUAL_ENV/bin:$PATH"\n'
    )
    path = os.environ.get("PATH", "/usr/bin:/bin")
    path = ":".join(
        p for p in path.split(":") if Path(p).resolve() != VENV_BIN.resolve()
    )  # the reader has not activated yet
    return {
        **os.environ,
        "PATH": path,
        "FLEETSIM_ENDPOINT": endpoint,
        "PYTHONUNBUFFERED": "1",
        "TERM": "xterm-256color",
    }


@dataclass
class Terminal:
    """A command running in a terminal of its own: a process group, or a tmux session."""

    name: str
    proc: subprocess.Popen[bytes] | None = None
    log: Path | None = None
    tmux_session: str = ""
    exit_file: Path | None = None

    def output(self) -> str:
        return self.log.read_text(errors="replace") if self.log and self.log.exists() else ""


class Run:
    """The page's steps, executed one after another in ``cwd``."""

    def __init__(self, cwd: Path, pictures: Path | None = None, echo: Callable[[str], None] | None = None) -> None:
        self.cwd = cwd
        self.pictures = pictures
        self.echo = echo or (lambda s: None)
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.env = make_checkout(cwd, self.endpoint, free_port())
        self.terms: dict[str, Terminal] = {}
        self.tmux = [TMUX or "tmux", "-L", f"fleetsim-tutorial-{uuid.uuid4().hex[:8]}", "-f", "/dev/null"]
        self.tmux_started = False
        self.browser: Chromium | None = None
        self.outputs: list[tuple[Step, str]] = []  # every command's real output, for the pictures script

    # -- the steps ----------------------------------------------------------------------------

    def step(self, s: Step) -> None:
        self.echo(f"{s.where()}: {s.kind} {' '.join(s.args)} {s.text.splitlines()[0] if s.text else ''}".rstrip())
        getattr(self, "_" + s.kind)(s)

    def _run(self, s: Step) -> None:
        if "source .venv/bin/activate" in s.text:  # the page asks it of every terminal from here on
            self.env["PATH"] = f"{self.cwd / '.venv' / 'bin'}:{self.env['PATH']}"
        want = int(s.options.get("status", "0"))
        done = subprocess.run(
            ["bash", "-e", "-c", command_of(s)], cwd=self.cwd, env=self.env,
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=60,
        )  # fmt: skip
        out = done.stdout
        self.outputs.append((s, out))
        assert done.returncode == want, f"{s.where()}: exit status {done.returncode}, not {want}:\n{out}"
        if s.sample:
            miss = unmatched(s.sample, out)
            assert miss is None, f"{s.where()}: the sample line {miss!r} is not in what the command printed:\n{out}"

    def _background(self, s: Step) -> None:
        name = s.args[0]
        log = self.cwd.parent / f"{self.cwd.name}-{name}.log"
        with log.open("wb") as f:
            proc = subprocess.Popen(
                ["bash", "-c", command_of(s)], cwd=self.cwd, env=self.env, stdout=f, stderr=subprocess.STDOUT,
                start_new_session=True, preexec_fn=_default_sigint,
            )  # fmt: skip
        term = self.terms[name] = Terminal(name, proc=proc, log=log)
        if s.sample:
            ok = wait_until(lambda: unmatched(s.sample, term.output()) is None or proc.poll() is not None, 30)
            miss = unmatched(s.sample, term.output())
            assert ok and miss is None, f"{s.where()}: {name} did not print {miss!r}:\n{term.output()}"
        self.outputs.append((s, term.output()))

    def _tmux(self, s: Step) -> None:
        assert TMUX is not None, "tmux is not installed"
        exports = " ".join(f"{k}={shlex.quote(self.env[k])}" for k in ("PATH", "FLEETSIM_ENDPOINT", "PYTHONUNBUFFERED"))
        names = []
        commands = [line for line in command_of(s).splitlines() if line.strip() and not line.startswith("#")]
        for k, line in enumerate(commands):
            name = s.args[0] + (str(k + 1) if k else "")
            exit_file = self.cwd.parent / f"{self.cwd.name}-{name}.exit"
            shell = f"export {exports}; {line.split('#')[0].strip()}; echo $? > {shlex.quote(str(exit_file))}"
            verb = ["new-session", "-d", "-s", name, "-x", "100", "-y", "14", "-c", str(self.cwd), shell]
            subprocess.run([*self.tmux, *verb], check=True, env=self.env)
            self.tmux_started = True
            self.terms[name] = Terminal(name, tmux_session=name, exit_file=exit_file)
            names.append(name)
        for name in names:  # a teleop takes keys once it found its robot
            ok = wait_until(lambda: all("[robot alive]" in self.pane(n) for n in names), 15)
            assert ok, f"{s.where()}: {name}:\n{self.pane(name)}"
        if "keys" in s.options:
            self._keys(Step("keys", s.line, [s.args[0], s.options["keys"]]))
        exact = s.options.get("exact", "")
        ok = wait_until(lambda: all(exact in self.pane(n) for n in names), 10)  # every screen, to the digit
        assert ok, f"{s.where()}: not every terminal shows {exact!r}:\n" + "\n".join(self.pane(n) for n in names)
        if s.sample:
            first = names[0]
            ok = wait_until(lambda: unmatched(s.sample, self.pane(first)) is None, 10)
            assert ok, (
                f"{s.where()}: the screen does not show {unmatched(s.sample, self.pane(first))!r}:\n{self.pane(first)}"
            )
        self.outputs.append((s, self.pane(names[0])))

    def pane(self, name: str) -> str:
        done = subprocess.run([*self.tmux, "capture-pane", "-p", "-t", f"={name}:"], capture_output=True, text=True)
        return done.stdout

    def _terminals(self, name: str) -> Iterator[Terminal]:
        found = [t for n, t in self.terms.items() if n == name or (n.startswith(name) and n[len(name) :].isdigit())]
        assert found, f"no terminal {name!r}"
        yield from found

    def _keys(self, s: Step) -> None:
        keys = []
        for word in s.args[1].split():
            key, _, times = word.partition("*")
            keys += [key] * int(times or 1)
        for term in self._terminals(s.args[0]):
            for key in keys:  # one at a time, as typed: the teleop counts presses
                subprocess.run([*self.tmux, "send-keys", "-t", f"={term.tmux_session}:", key], check=True)

    def _stop(self, s: Step) -> None:
        for term in self._terminals(s.args[0]):
            if term.proc is not None:
                if term.proc.poll() is None:
                    os.killpg(term.proc.pid, signal.SIGINT)
                try:
                    term.proc.wait(15)
                except subprocess.TimeoutExpired:
                    raise AssertionError(f"{s.where()}: {term.name} did not stop on Ctrl-C:\n{term.output()}") from None
                assert term.proc.returncode == 0, (
                    f"{s.where()}: {term.name} ended with {term.proc.returncode}:\n{term.output()}"
                )
            else:
                subprocess.run([*self.tmux, "send-keys", "-t", f"={term.tmux_session}:", "C-c"], check=True)
                self._ended(s, term)
            del self.terms[term.name]

    def _ended(self, s: Step, term: Terminal) -> None:
        assert term.exit_file is not None
        exit_file = term.exit_file
        assert wait_until(exit_file.exists, 15), f"{s.where()}: {term.name} is still running:\n{self.pane(term.name)}"
        assert wait_until(lambda: exit_file.read_text().strip() != "", 2)
        assert exit_file.read_text().strip() == "0", f"{s.where()}: {term.name} ended with {exit_file.read_text()}"

    def _wait(self, s: Step) -> None:
        for term in list(self._terminals(s.args[0])):
            if term.proc is not None:
                try:
                    rc = term.proc.wait(60)
                except subprocess.TimeoutExpired:
                    raise AssertionError(f"{s.where()}: {term.name} did not end:\n{term.output()}") from None
                assert rc == 0, f"{s.where()}: {term.name} ended with {rc}:\n{term.output()}"
                miss = unmatched(s.sample, term.output(), ordered=False)  # in the order things ended
                assert miss is None, f"{s.where()}: {term.name} did not print {miss!r}:\n{term.output()}"
                self.outputs.append((s, term.output()))
            else:
                self._ended(s, term)
            del self.terms[term.name]

    def _file(self, s: Step) -> None:
        (self.cwd / s.args[0]).write_text(s.text + "\n")

    def _shown(self, s: Step) -> None:
        for line in s.text.replace("\\\n", " ").splitlines():
            for part in re.split(r"&&|\|\||;|&", line.split(" #")[0]):
                words = shlex.split(part)
                if words and words[0] in PROGRAMS[:-2]:
                    check_flags(words, s.where())
                for word in words:  # files of the checkout it names (rviz2 -d docs/ros2/fleetsim.rviz)
                    if word.startswith("docs/"):
                        assert (ROOT / word).exists(), f"{s.where()}: {word} is not in the checkout"

    def _browser(self, s: Step) -> None:
        term = self.terms[s.args[0]]
        m = re.search(r"http://[\w.:]+/?", term.output())
        assert m, f"{s.where()}: {s.args[0]} printed no URL:\n{term.output()}"
        if self.browser is None:
            self.browser = Chromium(self.cwd.parent / f"{self.cwd.name}-chromium", width=1100, height=760)
        browser = self.browser
        if browser.evaluate("location.href").rstrip("/") != m.group(0).rstrip("/"):
            browser.navigate(m.group(0))
        try:
            browser.wait_for(s.args[1], 20)
        except Exception as e:
            stats = browser.evaluate("JSON.stringify(viewerStats)")
            raise AssertionError(f"{s.where()}: the page never showed {s.args[1]}: {e}\n{stats}") from None
        if "picture" in s.options:
            browser.evaluate("viewerStats.select(null)")
            frames = browser.evaluate("viewerStats.frames")
            browser.wait_for(f"viewerStats.frames > {frames} + 2")
            self._save_picture(s.options["picture"], browser.screenshot())

    def _picture(self, s: Step) -> None:
        path = self.cwd / s.args[0]
        data = path.read_bytes()
        assert data.startswith(b"\x89PNG"), f"{s.where()}: {path} is not a PNG"
        self._save_picture(s.args[1], data)

    def _save_picture(self, name: str, png: bytes) -> None:
        if self.pictures is not None:
            (self.pictures / name).write_bytes(png)

    def context(self) -> str:
        """What the terminals still open show (the last lines), for a failure's message."""
        out = []
        for name, term in self.terms.items():
            text = term.output() if term.proc is not None else self.pane(name)
            tail = "\n".join(f"    {line}" for line in text.rstrip().splitlines()[-12:])
            state = "running" if term.proc is None or term.proc.poll() is None else "ended"
            out.append(f"-- terminal {name} ({state}):\n{tail}")
        return "\n".join(out)

    # -- the end --------------------------------------------------------------------------------

    def close(self) -> None:
        """Whatever still runs (a failed run): stopped, as a reader would."""
        if self.browser is not None:
            self.browser.close()
        for term in self.terms.values():
            if term.proc is not None and term.proc.poll() is None:
                os.killpg(term.proc.pid, signal.SIGINT)
                try:
                    term.proc.wait(10)
                except subprocess.TimeoutExpired:
                    os.killpg(term.proc.pid, signal.SIGKILL)
                    term.proc.wait()
        if self.tmux_started:
            subprocess.run([*self.tmux, "kill-server"], capture_output=True)


def check_flags(words: list[str], where: str) -> None:
    """A fleetsim command of a ```sh block, parsed by the program's own parser."""
    import argparse
    import contextlib
    import io

    from clients.fleet_args import build_parser as fleet_parser
    from clients.mapping.cli import build_parser as map_parser
    from clients.record.cli import build_parser as record_parser
    from clients.ros.cli import build_parser as ros_parser
    from clients.teleop.cli import build_parser as teleop_parser
    from clients.viewer.app import build_parser as view_parser
    from simd.cli import build_parser as simd_parser

    parsers: dict[str, Callable[[], argparse.ArgumentParser]] = {
        "simd": simd_parser, "fleet-teleop": teleop_parser, "fleet-map": map_parser,
        "fleet-record": record_parser, "fleet-ros": ros_parser, "fleet-view": view_parser,
    }  # fmt: skip
    args = words[1:]
    if words[0] == "fleet":  # one parser per command
        parser = fleet_parser()[1][args[0]]
        args = args[1:]
    else:
        assert words[0] in parsers, f"{where}: no parser known for {words[0]}"
        parser = parsers[words[0]]()
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            parser.parse_args(args)
    except SystemExit as e:
        said = err.getvalue().strip().splitlines() or ["(nothing)"]
        raise AssertionError(f"{where}: {shlex.join(words)}: {said[-1]}") from e


def run_page(cwd: Path, pictures: Path | None = None, echo: Callable[[str], None] | None = None) -> Run:
    """Every step of the page, in order; raises AssertionError at the first that does not do
    what the page says."""
    steps = parse(PAGE.read_text())
    run = Run(cwd, pictures, echo)
    try:
        for s in steps:
            try:
                run.step(s)
            except AssertionError as e:
                raise AssertionError(f"{e}\n{run.context()}") from None
        assert not run.terms, f"the page ends with {sorted(run.terms)} still running: say how to stop them"
    finally:
        run.close()
    return run
