"""A pi2cma rollout worker in Python: your task's rollouts in your own Python process (a MuJoCo or
PyBullet simulation, a robot's driver) behind the pipeline, over iceoryx2 shared memory.

What it is: the wire protocol of crates/wire (README, "Wire layout") spoken with the `iceoryx2`
PyPI package (0.10, the version the Rust side uses) -- the same loop as the Rust
`pipeline::worker::serve`. What it is not: a second implementation of anything else; the update
rule, the sampler and the supervisor stay in Rust.

Use: a task object with `parameters`, `steps`, `settings` (a dict, the names of
`[task.external.settings]`), `set(name, value)` and `rollout(theta) -> (per_step_costs,
terminal_cost)`, and a script whose main is `pi2cma_worker.serve(make_task)`. Name the script
in `[task.external] worker`; the supervisor starts, restarts and scales it like its own workers
(tools/reach_worker.py and config/external-reach-python.toml are the example). A `set` that
raises refuses that change: the rollouts run with the value the update before ran with, their
costs say so, and the run goes on without the change (a value already in force before, such as
the config's at the first update, leaves nothing to fall back to, and the worker stops).

Stopping: SIGTERM or SIGINT (the supervisor's stop, Ctrl-C, a scale-down) ends the worker at
once, with exit code 0, also while the task is built (`make_task`) or in the middle of a rollout
that takes seconds: there the signal raises `Stopped` (a BaseException, as KeyboardInterrupt is)
inside the task's `__init__` or `rollout`, so its
`finally` blocks and context managers run (close your simulator there), and the rollout is
abandoned: its cost is never sent, and the sampler hands it to another worker (a scale-down) or
the update stays unfinished (a stop). Between rollouts the signal only ends the loop.
"""

import argparse
import ctypes
import inspect
import os
import signal
import struct
import sys
import time
import tomllib
import traceback

EXIT_CONFIG_REFUSED = 78

try:
    import iceoryx2 as iox2
except ImportError as e:
    # A restart would meet the same: exit with the code the supervisor does not restart.
    print(
        f"pi2cma_worker: cannot import iceoryx2 ({e}); install the tools' requirements: "
        "pip install -r tools/requirements.txt",
        file=sys.stderr,
    )
    sys.exit(EXIT_CONFIG_REFUSED)

# Errors only, as the Rust processes (pipeline::run_main): iceoryx2's notes ("No config file was
# loaded", "Detected dead node ... stale resources") are not the worker's output. IOX2_LOG_LEVEL
# overrides it.
iox2.set_log_level_from_env_or(iox2.LogLevel.Error)

MAX_SETTINGS = 8
WAKE = iox2.EventId.new(1)
NO_CHUNK = 2**64 - 1
QUEUE_EMPTY = 1
# Ready.flags: a rollout of the chunk other than its last is done (crates/wire Ready::ROLLOUT_DONE);
# sent at most every ROLLOUT_DONE_INTERVAL_S, only in a run with pipeline.rollout_timeout_ms,
# which then bounds one rollout rather than the whole chunk.
# Bits 16-31 of such a report count the chunk's rollouts whose costs have been sent (Ready::rollout_done):
# a lost worker's reported rollouts are then not run again while the update can finish without them.
ROLLOUT_DONE = 1
ROLLOUT_SENT_SHIFT = 16
ROLLOUT_DONE_INTERVAL_S = 0.001
ROLE_WORKER = 3
# Costs are announced to the updater at least this often while a chunk is being worked on.
NOTIFY_INTERVAL_S = 0.001


class WireStruct(ctypes.Structure):
    """A `#[repr(C)]` struct of crates/wire; iceoryx2 matches it by `WIRE_NAME`, the Rust side's
    `#[type_name]`."""

    WIRE_NAME = ""

    @classmethod
    def type_name(cls):
        return cls.WIRE_NAME


class WorkHeader(WireStruct):
    WIRE_NAME = "pi2cma.WorkHeader.v2"
    _fields_ = [
        ("run_id", ctypes.c_uint64),
        ("update", ctypes.c_uint64),
        ("chunk", ctypes.c_uint64),
        ("rollout", ctypes.c_uint32),
        ("chunk_len", ctypes.c_uint32),
        ("worker", ctypes.c_uint32),
        ("steps", ctypes.c_uint32),
        ("settings_len", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("settings", ctypes.c_double * MAX_SETTINGS),
        # What the update before ran with: where the task refuses a value of `settings`.
        ("previous_settings", ctypes.c_double * MAX_SETTINGS),
    ]


class CostHeader(WireStruct):
    WIRE_NAME = "pi2cma.CostHeader.v3"
    _fields_ = [
        ("run_id", ctypes.c_uint64),
        ("update", ctypes.c_uint64),
        ("rollout", ctypes.c_uint32),
        ("worker", ctypes.c_uint32),
        ("duration_ns", ctypes.c_uint64),
        ("terminal", ctypes.c_double),
        ("start_ns", ctypes.c_uint64),
        # The settings the rollout ran with (they differ from the work item's where the task
        # refused a change); settings_len 0: the work item's.
        ("settings_len", ctypes.c_uint32),
        ("_reserved", ctypes.c_uint32),
        ("settings", ctypes.c_double * MAX_SETTINGS),
    ]


class Ready(WireStruct):
    WIRE_NAME = "pi2cma.Ready.v2"
    _fields_ = [
        ("run_id", ctypes.c_uint64),
        ("chunk", ctypes.c_uint64),
        ("worker", ctypes.c_uint32),
        ("incarnation", ctypes.c_uint32),
        ("pid", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
    ]


class Lifecycle(WireStruct):
    WIRE_NAME = "pi2cma.Lifecycle.v1"
    _fields_ = [
        ("run_id", ctypes.c_uint64),
        ("pid", ctypes.c_uint32),
        ("role", ctypes.c_uint32),
        ("worker", ctypes.c_uint32),
        ("incarnation", ctypes.c_uint32),
    ]


for _t, _size in [(WorkHeader, 48 + 16 * MAX_SETTINGS), (CostHeader, 56 + 8 * MAX_SETTINGS), (Ready, 32), (Lifecycle, 24)]:
    assert ctypes.sizeof(_t) == _size, (_t.__name__, ctypes.sizeof(_t))


class WorkerError(Exception):
    pass


class TaskFailed(WorkerError):
    """The task's own code (`rollout`, `set`) raised, or returned what is not costs: the message
    names the call, the update and the rollout; `serve` prints the task's traceback before it."""


def _same(a, b):
    """Whether two setting values are the same bits, as the Rust worker and the updater compare
    them (with `==`, -0.0 and 0.0 are equal: a change from one to the other would be taken by a
    Rust worker and not by this one)."""
    return a is not None and b is not None and struct.pack("<d", a) == struct.pack("<d", b)


def _take(task, names, applied, target, which):
    """Sets the settings `which` to their values in `target`, in rounds: those the task refuses
    are tried again after a round that took any. Returns [(index, exception)] of those refused
    in the last round (a refused value must leave the task as it was)."""
    while True:
        refused = []
        for i in which:
            try:
                task.set(names[i], target[i])
                applied[i] = target[i]
            except Exception as e:
                refused.append((i, e))
        if not refused or len(refused) == len(which):
            return refused
        which = [i for i, _ in refused]


def _apply_settings(task, names, applied, refused, update, settings, previous):
    """The settings of a work item of `update`, on top of those the update before ran with
    (`previous`), as crates/pipeline/src/worker.rs (Applied::apply) does: the task is brought to
    `previous` first, then the update's changes are tried together (one refused is tried again
    once the others are in); one still refused keeps the value of `previous`, for every item of
    the update (`refused` holds them), so that all its rollouts run with the same settings."""
    decided = all(
        _same(applied[i], v) or (i, struct.pack("<d", v)) in refused for i, v in enumerate(settings)
    )
    if decided:
        return
    off = [i for i in range(len(settings)) if not _same(applied[i], previous[i])]
    for i, error in _take(task, names, applied, previous, off)[:1]:
        # A resumed run starts at the update after its recording's last: update 0 is a new
        # run's first, which runs with the config's values.
        if update == 0:
            in_force = "the config's value, which the run starts from"
        elif _same(settings[i], previous[i]):
            in_force = (
                "a value in force before this update: the config's, or an earlier change the "
                "other workers took"
            )
        else:
            in_force = "the value the update before ran with"
        # Refused as the config is (exit 78, not restarted): a restarted worker's task meets the
        # same value, and so does every other worker the rollouts go to.
        raise SettingRefused(
            f"update {update}: the task's set({names[i]!r}, {previous[i]!r}) raised "
            f"{type(error).__name__}: {error} ({in_force}): nothing to fall back to"
        ) from error
    changes = [i for i in range(len(settings)) if not _same(settings[i], previous[i])]
    for i, error in _take(task, names, applied, settings, changes):
        refused.add((i, struct.pack("<d", settings[i])))
        print(
            f"update {update}: the task's set({names[i]!r}, {settings[i]!r}) raised "
            f"{type(error).__name__}: {error}; its rollouts run with {names[i]} = "
            f"{previous[i]!r}, as the update before",
            file=sys.stderr,
            flush=True,
        )


class Stopped(BaseException):
    """Raised inside the task's `rollout` (or its construction) when SIGTERM or SIGINT arrives while it runs (the
    supervisor's stop, Ctrl-C, a scale-down), as Python raises KeyboardInterrupt: the task's
    `finally` blocks and context managers run, and the rollout is abandoned, its cost never
    sent. A BaseException, so that the task's `except Exception` does not catch it."""


class ConfigRefused(WorkerError):
    """The task has another shape than the run's config declares: a restart would refuse it
    again. Exits with 78 (crates/wire EXIT_CONFIG_REFUSED), which the supervisor does not
    restart."""


class SettingRefused(ConfigRefused, TaskFailed):
    """The task's `set` refused a value with nothing to fall back to (the config's own at the
    first update, or one the other workers took): refused as the config is, with the task's
    traceback."""


class Shape:
    """What the run's config declares, and the service sizes crates/wire derives from it."""

    def __init__(self, config_path):
        with open(config_path, "rb") as f:
            cfg = tomllib.load(f)
        ext = cfg.get("task", {}).get("external")
        if ext is None:
            raise WorkerError(f"{config_path}: has no [task.external] section")
        self.parameters = ext["parameters"]
        self.steps = ext["steps"]
        self.settings = sorted(ext.get("settings", {}))
        # N rows of P values, or None (see [task.external] basis_activations in the README).
        self.basis_activations = ext.get("basis_activations")
        self.rollouts = cfg["optimizer"]["rollouts"]
        self.max_workers = cfg.get("pipeline", {}).get("max_workers", 16)
        self.rollout_timeout_ms = cfg.get("pipeline", {}).get("rollout_timeout_ms")
        self.origin = config_path

    def nodes(self):
        return 2 * self.max_workers + 8

    def worker_ports(self):
        return 2 * self.max_workers + 2


def _service_name(run_id, tail):
    return iox2.ServiceName.new(f"pi2cma/{run_id:016x}/{tail}")


def _node(run_id, worker, incarnation):
    config = iox2.config.default()
    config.global_cfg.prefix = iox2.FileName.new(f"p2c{run_id:016x}_")
    config.global_cfg.root_path = iox2.Path.new(f"/tmp/p2c-{run_id:016x}/")
    return (
        iox2.NodeBuilder.new()
        .name(iox2.NodeName.new(f"worker-{worker}.{incarnation}"))
        .config(config)
        # Python's own SIGTERM handler below ends the loop; iceoryx2's would not be seen.
        .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
        .create(iox2.ServiceType.Ipc)
    )


class _RunEnd:
    """How a worker the supervisor did not start (or one behind a wrapper script without `exec`)
    learns that its run has ended, as crates/pipeline's RunEnd: the run directory, which the
    supervisor removes last, is gone; or the supervisor it has seen is gone without removing it
    (killed with SIGKILL). Looked at most once a second."""

    def __init__(self, run_dir, config):
        self.run_dir, self.config = run_dir, config
        self.supervisor_seen = False
        # Missing at the last look, with the run directory still there.
        self.supervisor_missed = False
        self.next_look = None

    def _supervisor_known_alive(self):
        # As wire::supervisor_known_alive: True for a live node named `supervisor`, False when
        # every node could be read and none is one, None when that cannot be told (a registry
        # that cannot be listed, a node whose state or name cannot be read or is being created).
        try:
            states = iox2.Node.list(iox2.ServiceType.Ipc, self.config)
        except Exception:
            return None
        found = False
        for state in states:
            if isinstance(state, iox2.NodeState.Dead):
                continue
            details = state[0].details if isinstance(state, iox2.NodeState.Alive) else None
            if details is None:
                found = None
            elif details.name.as_str() == "supervisor":
                return True
        return found

    def ended(self):
        now = time.monotonic()
        if self.next_look is not None and now < self.next_look:
            return None
        self.next_look = now + 1.0
        if not os.path.isdir(self.run_dir):
            return f"its run directory {self.run_dir} is gone"
        # Only a supervisor seen for certain is missed: a node being created reads as unknown.
        alive = self._supervisor_known_alive()
        if alive:
            self.supervisor_seen, self.supervisor_missed = True, False
        elif alive is False and self.supervisor_missed:
            return "its supervisor was killed; the next `supervisor run` removes what it left"
        elif alive is False and self.supervisor_seen:
            # One that ends in order removes its node, then the run directory a moment later:
            # look again soon rather than take it for killed.
            self.supervisor_missed = True
            self.next_look = now + 0.1
        return None


def _shape_attribute(task, name, what):
    """The task's attribute `name`, or ConfigRefused naming it: a task written after the Rust
    trait (`def settings(self)`) or without the attribute failed with `TypeError: 'method' object
    is not iterable` or an AttributeError, named neither the attribute nor what it must be, and
    was restarted up to the restart limit although every restart meets the same."""
    try:
        value = getattr(task, name)
    except AttributeError:
        raise ConfigRefused(f"the task has no attribute `{name}`: it must be {what}") from None
    if callable(value):
        raise ConfigRefused(
            f"the task's `{name}` is a method: it must be {what}, an attribute (or a property)"
        )
    return value


def _check_shape(task, shape):
    settings = _shape_attribute(
        task, "settings", "a dict of the names of [task.external.settings] and their values ({} for none)"
    )
    if not hasattr(settings, "keys"):
        raise ConfigRefused(
            f"the task's `settings` is {_short(settings)}: it must be a dict of the names of "
            f"[task.external.settings] and their values"
        )
    theirs = sorted(settings)
    for what, ours, declared in [
        ("parameters", _shape_attribute(task, "parameters", "P, the length of theta"), shape.parameters),
        ("steps", _shape_attribute(task, "steps", "N, the number of step costs"), shape.steps),
        ("settings", theirs, shape.settings),
    ]:
        if ours != declared:
            raise ConfigRefused(
                f"the task has {what} {ours}, but task.external.{what} = {declared} "
                f"in {shape.origin}"
            )
    # A task that knows its policy's activations (an attribute, N rows of P values) must have
    # the config's: the update weighs the rollouts by those.
    own = getattr(task, "basis_activations", None)
    if own is not None and shape.basis_activations is not None:
        own = [list(map(float, row)) for row in own]
        if own != shape.basis_activations:
            raise ConfigRefused(
                f"the task has other basis activations than task.external.basis_activations "
                f"in {shape.origin} ({_first_difference(own, shape.basis_activations)}): the "
                f"update weighs the rollouts by the config's, so put the task's own there"
            )


def _first_difference(own, declared):
    """Where a task's basis activations (rows of floats) first differ from the config's: the
    step and parameter with both values, or the shapes. Saying only that they differ left a user
    to compare hundreds of numbers by eye."""
    for i, (a, b) in enumerate(zip(own, declared)):
        if len(a) != len(b):
            return f"step {i}: the task's {len(a)} values, the config's {len(b)}"
        for j, (x, y) in enumerate(zip(a, b)):
            if x != y:
                return f"at step {i}, parameter {j}: the task's {x!r}, the config's {y!r}"
    return f"the task's are {len(own)} rows, the config's {len(declared)}"


def serve(make_task, argv=None):
    """Parses the supervisor's arguments, builds the task with `make_task(shape)` (a `Shape`:
    what the config declares: `parameters`, `steps`, `settings` (the names, sorted, not their
    values: those come through `task.set`), `basis_activations`, ...), or
    with `make_task()` unless its first parameter must be given or is named `shape` (see
    `_takes_an_argument`), and
    runs rollouts until SIGTERM/SIGINT (in a rollout too: see `Stopped`) or the end of the run
    (its run directory gone). Exits the process: 0 when stopped, 1 on an error, 78 when the task
    does not match the config."""
    # The docstring's first paragraph (its first line ends mid-sentence).
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--config", required=True)
    p.add_argument("--run-dir", required=True)
    p.add_argument("--run-id", required=True, type=lambda s: int(s, 16))
    p.add_argument("--worker", required=True, type=int)
    p.add_argument("--incarnation", type=int, default=0)
    args = p.parse_args(argv)
    name = os.path.basename(sys.argv[0])
    try:
        _serve(make_task, args)
    except ConfigRefused as e:
        if e.__cause__ is not None:
            traceback.print_exception(e.__cause__, file=sys.stderr)
        print(f"error: {name} failed: {e}", file=sys.stderr, flush=True)
        sys.exit(EXIT_CONFIG_REFUSED)
    except WorkerError as e:
        # The task's traceback first: the supervisor reports the last line, this summary.
        if e.__cause__ is not None:
            _print_traceback(e.__cause__, args)
        print(f"error: {name} failed: {e}", file=sys.stderr, flush=True)
        sys.exit(1)
    except Exception as e:  # an iceoryx2 error or a failing task: report it, as the Rust side does
        _print_traceback(e, args)
        print(f"error: {name} failed: {type(e).__name__}: {e}", file=sys.stderr, flush=True)
        sys.exit(1)
    sys.exit(0)


def _print_traceback(e, args):
    """Prints `e`'s traceback on stderr, unless this worker's previous incarnation printed the
    same one: then a line that says so. A task that fails the same way at every restart printed
    its whole traceback once per restart, burying the other lines of the run. The traceback is
    kept in the run directory (`worker-<w>.traceback`) for the next incarnation."""
    text = "".join(traceback.format_exception(type(e), e, e.__traceback__))
    kept = os.path.join(args.run_dir, f"worker-{args.worker}.traceback")
    before = None
    try:
        with open(kept) as f:
            incarnation, _, before = f.read().partition("\n")
    except OSError:
        pass
    if before == text:
        print(
            f"(the same traceback as incarnation {incarnation}'s, printed before)",
            file=sys.stderr,
            flush=True,
        )
    else:
        print(text, end="", file=sys.stderr, flush=True)
    try:
        with open(kept, "w") as f:
            f.write(f"{args.incarnation}\n{text}")
    except OSError:  # a run directory gone or read-only: print in full next time
        pass


def _takes_an_argument(make_task):
    """Whether `make_task` is called with the shape: when its first parameter must be given,
    or is named `shape`. A class whose `__init__` takes nothing, or only options with defaults
    (`def __init__(self, gain=1.0)`: the shape is not a gain), is called without it."""
    try:
        sig = inspect.signature(make_task)
    except (TypeError, ValueError):  # a builtin without a signature: assume the documented form
        return True
    try:
        sig.bind()
    except TypeError:
        return True  # it needs an argument (if it cannot take one, Python says so)
    first = next(iter(sig.parameters.values()), None)
    if first is None:
        return False
    if first.kind == first.VAR_POSITIONAL:
        return True  # `*args`: a wrapper that passes on what it gets
    return first.name == "shape" and first.kind in (first.POSITIONAL_ONLY, first.POSITIONAL_OR_KEYWORD)


def _costs_of(result, n, where):
    """The task's `rollout` result as (N floats, a float), or a TaskFailed naming `where` (the
    update and rollout), the step and the value: a None or a string among the costs failed with
    only `TypeError: must be real number, not NoneType`, a tuple of another form with Python's
    unpacking error."""
    try:
        per_step, terminal = result
    except (TypeError, ValueError):
        raise TaskFailed(
            f"{where}: the task's rollout returned {_short(result)}, not (step_costs, terminal_cost)"
        ) from None
    try:
        count = len(per_step)
    except TypeError:
        raise TaskFailed(f"{where}: the task's rollout returned step costs {_short(per_step)}, not a sequence") from None
    if count != n:
        # Another shape than the config declares, as a wrong `steps` attribute is: every
        # restart would meet the same (exit 78, not restarted).
        raise ConfigRefused(
            f"{where}: the task's rollout returned {count} step costs, expected {n} (task.external.steps)"
        )
    values = []
    for i, v in enumerate(per_step):
        try:
            values.append(float(v))
        except (TypeError, ValueError):
            raise TaskFailed(f"{where}: the task's rollout returned step cost {i} = {_short(v)}, not a number") from None
    try:
        terminal = float(terminal)
    except (TypeError, ValueError):
        raise TaskFailed(f"{where}: the task's rollout returned terminal cost {_short(terminal)}, not a number") from None
    return values, terminal


def _short(value):
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _serve(make_task, args):
    stop = []
    # While the task is built or its rollout runs, a stop signal raises Stopped in it (once: a
    # second signal does not interrupt the task's cleanup); elsewhere it only ends the loop.
    in_task, interrupted = [False], [False]

    def on_signal(signum, _frame):
        stop.append(signum)
        if in_task[0]:
            in_task[0], interrupted[0] = False, True
            raise Stopped(signal.Signals(signum).name)

    for s in (signal.SIGTERM, signal.SIGINT):
        signal.signal(s, on_signal)
    shape = Shape(args.config)
    if not 0 <= args.worker < shape.max_workers:
        raise WorkerError(f"worker slot {args.worker} is beyond pipeline.max_workers = {shape.max_workers}")
    # A task whose start hangs (a simulator that waits for its license, a robot for its driver)
    # is stopped there too, not SIGKILLed after the supervisor's shutdown timeout.
    try:
        in_task[0] = True
        try:
            task = make_task(shape) if _takes_an_argument(make_task) else make_task()
        finally:
            in_task[0] = False
    except Stopped:
        pass
    if stop:
        print("stopped by a signal while the task was being built", flush=True)
        return
    _check_shape(task, shape)
    run_id, w, inc = args.run_id, args.worker, args.incarnation
    node = _node(run_id, w, inc)

    def bell(owner, listen=False):
        # The settings of crates/wire `doorbell`: this worker's own doorbell may not exist yet.
        service = (
            node.service_builder(_service_name(run_id, f"wake/{owner}"))
            .event()
            .max_notifiers(shape.worker_ports() + 4)
            .max_listeners(2)
            .max_nodes(shape.nodes())
            .event_id_max_value(2)
            .open_or_create()
        )
        return service.listener_builder().create() if listen else service.notifier_builder().create()

    # `work/<w>` is created by its worker (the sampler opens it when the worker asks for work):
    # the settings of crates/wire `work`. The other services exist; they are opened as they are.
    inbox = (
        node.service_builder(_service_name(run_id, f"work/{w}"))
        .publish_subscribe(iox2.Slice[ctypes.c_double])
        .user_header(WorkHeader)
        .max_publishers(2)
        .max_subscribers(2)
        .subscriber_max_buffer_size(max(shape.rollouts, 1))
        .subscriber_max_borrowed_samples(2)
        .history_size(0)
        .enable_safe_overflow(True)
        .max_nodes(8)
        .open_or_create()
        .subscriber_builder()
        .create()
    )
    doorbell = bell(f"worker/{w}", listen=True)
    costs = (
        node.service_builder(_service_name(run_id, "costs"))
        .publish_subscribe(iox2.Slice[ctypes.c_double])
        .user_header(CostHeader)
        .open()
        .publisher_builder()
        .initial_max_slice_len(shape.steps)
        .create()
    )
    ready = (
        node.service_builder(_service_name(run_id, "ready"))
        .publish_subscribe(Ready)
        .open()
        .publisher_builder()
        .create()
    )
    lifecycle = (
        node.service_builder(_service_name(run_id, "lifecycle"))
        .publish_subscribe(Lifecycle)
        .open()
        .publisher_builder()
        .create()
    )
    updater_bell, sampler_bell, supervisor_bell = bell("updater"), bell("sampler"), bell("supervisor")

    pid = os.getpid()
    lifecycle.send_copy(Lifecycle(run_id=run_id, pid=pid, role=ROLE_WORKER, worker=w, incarnation=inc))
    supervisor_bell.notify_with_custom_event_id(WAKE)
    # The sampler gives this worker work once the recorder has connected to it (it echoes the
    # announcement on `joined`): ring the recorder rather than wait for its tick.
    bell("recorder").notify_with_custom_event_id(WAKE)

    def publish_ready(chunk, flags=0):
        ready.send_copy(Ready(run_id=run_id, chunk=chunk, worker=w, incarnation=inc, pid=pid, flags=flags))

    publish_ready(NO_CHUNK)
    sampler_bell.notify_with_custom_event_id(WAKE)

    names = shape.settings
    applied = [None] * len(names)
    # The update of the work items last applied, and the (setting, value) its task refused in it.
    refused_update, refused = None, set()
    chunk, done_in_chunk = None, 0
    report_rollouts = shape.rollout_timeout_ms is not None
    reported_at = time.monotonic()
    last_notify = time.monotonic()
    n = shape.steps
    run_end = _RunEnd(args.run_dir, node.config)
    while not stop:
        why = run_end.ended()
        if why is not None:
            print(f"the run has ended ({why}): exiting", flush=True)
            break
        try:
            doorbell.timed_wait(iox2.Duration.from_millis(50))
        except iox2.ListenerWaitError as e:
            # A signal interrupted the wait; its handler has run or runs next, and the loop
            # condition sees it.
            if "Interrupt" in str(e):
                continue
            raise
        unannounced = False
        while not stop:
            item = inbox.receive()
            if item is None:
                break
            h = item.user_header().contents
            if h.run_id != run_id:
                continue
            # Slice.len() of iceoryx2 0.10's Python binding counts bytes; the header counts f64s.
            count = item.header.number_of_elements
            if count != shape.parameters or h.steps != n:
                raise WorkerError(
                    f"work item of update {h.update} has θ of length {count} and {h.steps} "
                    f"steps, expected {shape.parameters} and {n}"
                )
            theta = list((ctypes.c_double * count).from_address(item.payload().as_ptr()))
            update, rollout, chunk_id, chunk_len, flags = h.update, h.rollout, h.chunk, h.chunk_len, h.flags
            if chunk != chunk_id:
                chunk, done_in_chunk, reported_at = chunk_id, 0, time.monotonic()
            if update != refused_update:
                refused_update, refused = update, set()
            m = min(h.settings_len, len(names))
            _apply_settings(
                task, names, applied, refused, update, list(h.settings[:m]), list(h.previous_settings[:m])
            )
            item.delete()
            # The wall clock first, as the Rust worker does (see crates/pipeline/src/worker.rs).
            start_ns = time.time_ns()
            start = time.monotonic_ns()
            where = f"update {update}, rollout {rollout}"
            result = None
            try:
                in_task[0] = True
                try:
                    if stop:  # a signal after the loop's check: not a rollout begun
                        break
                    result = task.rollout(theta)
                finally:
                    in_task[0] = False
            except Stopped:
                pass
            except SystemExit as e:
                # The task ends its worker on purpose (an operator's stop button, a robot's
                # safety stop): say so, as the supervisor sees only the exit status. Status 0 is
                # a deliberate stop it does not restart; any other, a failure it does.
                quiet = e.code is None or e.code == 0
                how = (
                    "with status 0, stopped on purpose (the supervisor does not restart it)"
                    if quiet
                    else "with a failure status (the supervisor restarts it)"
                )
                print(
                    f"{where}: the task's rollout called sys.exit({e.code!r}): the worker exits "
                    f"{how}; the rollout is abandoned, its cost not sent",
                    flush=True,
                )
                raise
            except Exception as e:
                # The task turned Stopped into an error of its own: still a stop.
                if not interrupted[0]:
                    raise TaskFailed(f"{where}: the task's rollout raised {type(e).__name__}: {e}") from e
            if interrupted[0]:
                # Stopped mid-rollout (even if the task caught Stopped and returned): what it
                # returned is not this rollout's cost, so nothing is sent. The sampler hands the
                # chunk's rollouts to another worker once this one is gone.
                print(
                    f"{where}: stopped by a signal during the rollout; abandoned, its cost not sent",
                    flush=True,
                )
                break
            per_step, terminal = _costs_of(result, n, where)
            # Written straight into the loaned shared memory, as the Rust worker does.
            sample = costs.loan_slice_uninit(n)
            values = (ctypes.c_double * n).from_address(sample.payload().as_ptr())
            values[:] = per_step
            header = sample.user_header().contents
            header.run_id, header.update, header.rollout, header.worker = run_id, update, rollout, w
            header.duration_ns = time.monotonic_ns() - start
            header.terminal = terminal
            header.start_ns = start_ns
            # The header is not zeroed: every field is written.
            header.settings_len, header._reserved = (0 if None in applied else len(applied)), 0
            for i in range(MAX_SETTINGS):
                header.settings[i] = applied[i] if i < header.settings_len else 0.0
            sample.assume_init().send()
            unannounced = True
            done_in_chunk += 1
            chunk_done = done_in_chunk >= chunk_len
            now = time.monotonic()
            # Ready before the updater's bell, and not before the costs (see the wire protocol).
            if chunk_done:
                publish_ready(chunk_id)
            elif report_rollouts and now - reported_at >= ROLLOUT_DONE_INTERVAL_S:
                publish_ready(chunk_id, ROLLOUT_DONE | min(done_in_chunk, 0xFFFF) << ROLLOUT_SENT_SHIFT)
                reported_at = now
            if chunk_done or not inbox.has_samples() or now - last_notify >= NOTIFY_INTERVAL_S:
                updater_bell.notify_with_custom_event_id(WAKE)
                last_notify, unannounced = now, False
            if chunk_done and not flags & QUEUE_EMPTY:
                sampler_bell.notify_with_custom_event_id(WAKE)
        if unannounced:
            updater_bell.notify_with_custom_event_id(WAKE)
