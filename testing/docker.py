"""A Docker engine of the test suite's own, a Debian base image made without a registry, and
the project's image built on it — for ``tests/docker/test_smoke.py``.

No image registry is reachable from the machines this suite runs on, so nothing is pulled:

* :func:`start_engine` runs ``dockerd`` with its own data root, exec root, pid file, socket and
  (empty) configuration under :func:`cache_dir`; the client reaches it through ``DOCKER_HOST``.
  The data root is kept between runs — it is the cache of the base image and of the build's
  layers — while :func:`stop_engine` stops the daemon and removes what it leaves on the host:
  mounts under the cache, the ``docker0`` (and any ``br-…``) bridge, the ``DOCKER*`` iptables
  chains and the rules that jump to them or name those bridges, and the kernel settings dockerd
  changed (put back as they were). A run that was killed is cleaned up by the next one: its
  dockerd, containerd, shims and container processes are stopped first.
* :func:`ensure_base_image` makes ``local/<codename>-python:<key>`` with ``debootstrap
  --variant=minbase`` from the Debian mirror this machine's apt uses (read at run time from its
  sources; never written anywhere), with python3 and its venv module, and with the host's CA
  bundle so that pip inside a build trusts what the host trusts (HTTPS may pass a proxy with its
  own CA). The rootfs is kept as a tarball beside the data root; the key covers the recipe and the
  CA bundle, so either changing makes a new base.
* :func:`build_project_image` builds ``docker/Dockerfile`` on that base, passing the host's pip
  index and proxy settings as build arguments, and only those that the host actually has.

Everything needs root (dockerd, debootstrap, iptables); a missing engine or debootstrap is
installed by ``.ci/setup-system`` when possible and otherwise reported in one line.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
HOST_CA_BUNDLE = Path("/etc/ssl/certs/ca-certificates.crt")
# In the base, the host's bundle is both the default bundle and a file of its own that the
# TLS variables name: installing Debian's ca-certificates later (as the Dockerfile's apt step may)
# rewrites the default bundle from Debian's list, but folds in this local one, and the variables
# still name a file with the host's CAs.
BASE_CA_FILE = "/usr/local/share/ca-certificates/host-ca-bundle.crt"
# Bump when the way the base is made changes: a new key makes a new base.
BASE_RECIPE = "debootstrap minbase + python3 python3-venv, host CA, no apt sources; v3"
BASE_PACKAGES = ("python3", "python3-venv")
PROJECT_IMAGE = "local/ergoseek:smoke"
SMOKE_LABEL = "ergoseek.smoke"
# Kernel settings dockerd changes; put back as they were when the engine stops.
SYSCTLS = (
    "net/ipv4/ip_forward",
    "net/bridge/bridge-nf-call-iptables",
    "net/bridge/bridge-nf-call-ip6tables",
)


def _path() -> str:
    """PATH with the sbin directories (dockerd, iptables, debootstrap) even when a user's or a
    CI's PATH lacks them; dockerd finds containerd, runc and iptables through it too."""
    parts = os.environ.get("PATH", "/usr/bin:/bin").split(os.pathsep)
    return os.pathsep.join(
        parts + [d for d in ("/usr/local/sbin", "/usr/sbin", "/sbin") if d not in parts]
    )


def _which(tool: str) -> str | None:
    return shutil.which(tool, path=_path())


class DockerSetupError(RuntimeError):
    """Something this machine lacks for the Docker smoke test; the message says what."""


def cache_dir() -> Path:
    """Where the engine's data root, the base rootfs tarball and the logs live between runs."""
    env = os.environ.get("ERGOSEEK_DOCKER_CACHE")
    return Path(env) if env else Path("/var/tmp/ergoseek-docker")


def _run(
    cmd: Sequence[str],
    *,
    timeout: float = 120.0,
    check: bool = True,
    env: dict[str, str] | None = None,
    **kw: object,
) -> subprocess.CompletedProcess[str]:
    env = env if env is not None else {**os.environ, "PATH": _path()}
    proc = subprocess.run(
        list(cmd), capture_output=True, text=True, timeout=timeout, env=env, check=False, **kw
    )
    if check and proc.returncode != 0:
        out = (proc.stdout + proc.stderr).strip()[-3000:]
        raise DockerSetupError(f"{shlex.join(cmd[:4])}… failed ({proc.returncode}):\n{out}")
    return proc


# --------------------------------------------------------------------------- prerequisites


def ensure_prerequisites() -> None:
    """Root, dockerd, a docker client, debootstrap and iptables; installs the Debian packages
    (``docker.io``, ``debootstrap``) through ``.ci/setup-system`` when they are missing."""
    if os.geteuid() != 0:
        raise DockerSetupError(
            "the Docker smoke test runs its own dockerd and debootstrap: it needs root"
        )
    tools = ("dockerd", "docker", "debootstrap", "iptables", "ip")
    if any(_which(t) is None for t in tools):
        setup = REPO / ".ci" / "setup-system"
        proc = subprocess.run(
            [str(setup)], capture_output=True, text=True, timeout=600, check=False
        )
        missing = [t for t in tools if _which(t) is None]
        if missing:
            raise DockerSetupError(
                f"missing {', '.join(missing)}; .ci/setup-system (apt-get install docker.io "
                f"debootstrap) exited {proc.returncode}: {(proc.stdout + proc.stderr)[-800:]}"
            )


def docker_client() -> str:
    """The client shipped with the engine (same version as dockerd) when there is one."""
    dockerd = _which("dockerd")
    if dockerd:
        for d in (Path(dockerd).parent, Path("/usr/bin")):
            if (d / "docker").is_file():
                return str(d / "docker")
    found = _which("docker")
    if not found:
        raise DockerSetupError("no docker client on PATH")
    return found


# --------------------------------------------------------------------------- apt sources


def _deb822_stanzas(text: str) -> Iterator[dict[str, str]]:
    for block in re.split(r"\n\s*\n", text):
        fields: dict[str, str] = {}
        key = None
        for line in block.splitlines():
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            if line[0].isspace() and key:
                fields[key] += " " + line.strip()
                continue
            key, _, value = line.partition(":")
            key = key.strip().lower()
            fields[key] = value.strip()
        if fields:
            yield fields


def host_codename() -> str:
    try:
        text = Path("/etc/os-release").read_text()
    except OSError:
        return "bookworm"
    m = re.search(r"^VERSION_CODENAME=\"?([a-z]+)\"?$", text, re.M)
    return m.group(1) if m else "bookworm"


def debian_mirror(codename: str) -> tuple[str, str]:
    """(mirror URI, the file it came from) of the apt source that serves ``codename`` itself
    (not -updates or -security): deb822 ``*.sources`` first, then one-line ``*.list`` files."""
    apt = Path("/etc/apt")
    candidates: list[tuple[str, str, Path]] = []  # (uri, suite, file)
    for f in sorted((apt / "sources.list.d").glob("*.sources")):
        for st in _deb822_stanzas(f.read_text(errors="replace")):
            if st.get("enabled", "yes").lower() == "no" or "deb" not in st.get("types", ""):
                continue
            for uri in st.get("uris", "").split():
                for suite in st.get("suites", "").split():
                    candidates.append((uri, suite, f))
    lists = [apt / "sources.list", *sorted((apt / "sources.list.d").glob("*.list"))]
    for f in lists:
        if not f.is_file():
            continue
        for line in f.read_text(errors="replace").splitlines():
            words = re.sub(r"\[[^]]*\]", " ", line.split("#", 1)[0]).split()
            if len(words) >= 3 and words[0] == "deb":
                candidates.append((words[1], words[2], f))
    for uri, suite, f in candidates:
        if suite == codename and uri.split(":", 1)[0] in {"http", "https", "ftp", "file"}:
            return uri, str(f)
    raise DockerSetupError(
        f"no apt source for {codename!r} in /etc/apt/sources.list(.d): debootstrap needs a mirror"
    )


# --------------------------------------------------------------------------- the engine


@dataclass
class Engine:
    """A running dockerd of ours and the environment its client needs."""

    root: Path
    client: str
    env: dict[str, str]
    proc: subprocess.Popen[bytes] | None = None
    timings: dict[str, float | str] = field(default_factory=dict)

    def docker(
        self, *args: str, timeout: float = 120.0, check: bool = True, **kw: object
    ) -> subprocess.CompletedProcess[str]:
        return _run([self.client, *args], timeout=timeout, check=check, env=self.env, **kw)

    def image_exists(self, ref: str) -> bool:
        return self.docker("image", "inspect", ref, check=False, timeout=30).returncode == 0


def _paths(root: Path) -> dict[str, Path]:
    return {
        "data": root / "data",
        "exec": root / "exec",
        "run": root / "run",
        "sock": root / "run" / "docker.sock",
        "pid": root / "run" / "dockerd.pid",
        "config": root / "run" / "daemon.json",
        "state": root / "run" / "host-state.json",
        "log": root / "dockerd.log",
        "client": root / "client",
    }


def _processes() -> Iterator[tuple[int, str, str]]:
    """(pid, comm, cmdline) of every process."""
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            comm = (d / "comm").read_text().strip()
            cmdline = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        yield int(d.name), comm, cmdline


def _ours(root: Path) -> list[tuple[int, str]]:
    """(pid, comm) of the dockerd, containerd, shims and proxies started for this cache (their
    command lines name it) and of the processes in its containers (their cgroups name them)."""
    containers = root / "data" / "containers"
    ids = [d.name for d in containers.iterdir()] if containers.is_dir() else []
    found = []
    for pid, comm, cmd in _processes():
        if pid == os.getpid():
            continue
        if str(root) in cmd and comm.startswith(("dockerd", "containerd", "docker-")):
            found.append((pid, comm))
        elif ids:
            try:
                cgroup = Path(f"/proc/{pid}/cgroup").read_text()
            except OSError:
                continue
            if any(i in cgroup for i in ids):
                found.append((pid, comm))
    return found


def foreign_dockerd(root: Path) -> list[int]:
    """Other Docker engines on this machine (they own docker0 and the DOCKER chains)."""
    return [pid for pid, comm, cmd in _processes() if comm == "dockerd" and str(root) not in cmd]


def _kill(pids: Sequence[int], timeout: float) -> None:
    for sig in (signal.SIGTERM, signal.SIGKILL):
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, sig)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if not any(Path(f"/proc/{p}").exists() for p in pids):
                return
            time.sleep(0.1)


def _unmount_under(*dirs: Path) -> list[str]:
    """Unmount everything mounted below ``dirs``, deepest first; returns what was unmounted."""
    prefixes = tuple(str(d.resolve()) + "/" for d in dirs)
    points = []
    for line in Path("/proc/self/mountinfo").read_text().splitlines():
        point = line.split()[4].replace("\\040", " ")
        if point.startswith(prefixes) or point + "/" in prefixes:
            points.append(point)
    done = []
    for point in sorted(set(points), key=len, reverse=True):
        if _run(["umount", point], check=False).returncode != 0:
            _run(["umount", "-l", point], check=False)
        done.append(point)
    return done


DOCKER_BRIDGE = re.compile(r"^(docker0|br-[0-9a-f]{12})$")  # the default and Compose's networks


def _hairpin(words: list[str]) -> bool:
    """Docker's rule for a published port reached from its own container:
    ``-A POSTROUTING -s A/32 -d A/32 -p tcp -m tcp --dport P -j MASQUERADE``."""

    def arg(flag: str) -> str | None:
        return words[words.index(flag) + 1] if flag in words[:-1] else None

    src = arg("-s")
    return (
        words[1] == "POSTROUTING"
        and arg("-j") == "MASQUERADE"
        and src is not None
        and src.endswith("/32")
        and src == arg("-d")
        and arg("--dport") is not None
    )


def _iptables_cleanup() -> list[str]:
    """Remove the DOCKER* chains and every rule that jumps to them or names a Docker bridge."""
    removed = []
    for table in ("nat", "filter"):
        listing = _run(["iptables", "-t", table, "-S"], check=False)
        if listing.returncode != 0:
            continue
        lines = listing.stdout.splitlines()
        for line in lines:
            words = shlex.split(line)
            if len(words) < 2 or words[0] != "-A" or words[1].startswith("DOCKER"):
                continue
            if any(DOCKER_BRIDGE.match(w) or w.startswith("DOCKER") for w in words[2:]) or (
                _hairpin(words)
            ):
                _run(["iptables", "-t", table, "-D", *words[1:]], check=False)
                removed.append(f"{table}: {line}")
        chains = [
            w[1] for w in (ln.split() for ln in lines) if w[0] == "-N" and w[1].startswith("DOCKER")
        ]
        for verb in ("-F", "-X"):
            for chain in chains:
                _run(["iptables", "-t", table, verb, chain], check=False)
        removed += [f"{table}: chain {c}" for c in chains]
    return removed


def _read_sysctls() -> dict[str, str]:
    out = {}
    for name in SYSCTLS:
        with contextlib.suppress(OSError):
            out[name] = (Path("/proc/sys") / name).read_text().strip()
    return out


def _forward_policy() -> str | None:
    listing = _run(["iptables", "-t", "filter", "-S", "FORWARD"], check=False)
    m = re.search(r"^-P FORWARD (\w+)$", listing.stdout, re.M)
    return m.group(1) if m else None


def clean_host(root: Path) -> list[str]:
    """Stop what a previous run of ours left running and undo what it left on the host.

    Safe to call at any time: the bridge and the iptables chains are touched only when no other
    Docker engine runs on this machine (they would be that engine's)."""
    p = _paths(root)
    actions = []
    stale = _ours(root)
    if stale:
        # dockerd first: on SIGTERM it stops its containers and its containerd itself.
        _kill([pid for pid, comm in stale if comm == "dockerd"], 40.0)
        _kill([pid for pid, _ in _ours(root)], 10.0)
        actions.append(f"stopped leftover processes {sorted(c for _, c in stale)}")
    actions += [f"unmounted {m}" for m in _unmount_under(p["exec"], p["data"], root / "base")]
    if not foreign_dockerd(root):
        for link in sorted(Path("/sys/class/net").iterdir()):
            if DOCKER_BRIDGE.match(link.name) and (link / "bridge").is_dir():
                _run(["ip", "link", "delete", link.name], check=False)
                actions.append(f"deleted bridge {link.name}")
        actions += _iptables_cleanup()
        if p["state"].exists():
            state = json.loads(p["state"].read_text())
            for name, value in state.get("sysctls", {}).items():
                with contextlib.suppress(OSError):
                    (Path("/proc/sys") / name).write_text(value + "\n")
            if state.get("forward_policy"):
                _run(["iptables", "-P", "FORWARD", state["forward_policy"]], check=False)
            actions.append("restored sysctls and FORWARD policy")
    p["state"].unlink(missing_ok=True)
    shutil.rmtree(p["exec"], ignore_errors=True)
    for f in (p["sock"], p["pid"]):
        f.unlink(missing_ok=True)
    return actions


@contextlib.contextmanager
def engine_lock(root: Path, timeout: float = 1200.0) -> Iterator[None]:
    """One engine per cache at a time: a second test run on this machine waits its turn."""
    root.mkdir(parents=True, exist_ok=True)
    with (root / "lock").open("w") as fh:
        deadline = time.monotonic() + timeout
        while True:
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise DockerSetupError(
                        f"{root}/lock: another run kept it {timeout:.0f} s"
                    ) from None
                time.sleep(1.0)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def start_engine(root: Path, timeout: float = 60.0) -> Engine:
    """Start dockerd on ``root`` (after cleaning what an interrupted run left there)."""
    t0 = time.monotonic()
    p = _paths(root)
    others = foreign_dockerd(root)
    if others:
        raise DockerSetupError(
            f"another Docker engine runs here (pid {others}); the smoke test starts its own and "
            "would share docker0 and the DOCKER iptables chains with it: stop it first"
        )
    clean_host(root)
    for d in ("data", "exec", "run", "client"):
        p[d].mkdir(parents=True, exist_ok=True)
    p["config"].write_text("{}\n")
    p["state"].write_text(
        json.dumps({"sysctls": _read_sysctls(), "forward_policy": _forward_policy()}) + "\n"
    )
    env = {
        **os.environ,
        "DOCKER_HOST": f"unix://{p['sock']}",
        "DOCKER_CONFIG": str(p["client"]),  # not the user's ~/.docker (credential helpers…)
        "DOCKER_BUILDKIT": "0",  # no buildx here: the classic builder, without asking
        "PATH": _path(),
    }
    for var in ("DOCKER_CONTEXT", "DOCKER_TLS_VERIFY", "DOCKER_CERT_PATH"):
        env.pop(var, None)
    flags = {
        "--data-root": p["data"],
        "--exec-root": p["exec"],
        "--pidfile": p["pid"],
        "--host": env["DOCKER_HOST"],
        "--config-file": p["config"],  # not /etc/docker/daemon.json
        "--log-level": "warn",
    }
    cmd = [_which("dockerd") or "dockerd", *(a for f, v in flags.items() for a in (f, str(v)))]
    with p["log"].open("wb") as log:  # the last run's log only
        log.write(f"==== {time.ctime()} {shlex.join(cmd)}\n".encode())
        log.flush()
        proc = subprocess.Popen(
            cmd,
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            env=env,
            start_new_session=True,  # a Ctrl-C to pytest reaches the finalizer, not dockerd
        )
    engine = Engine(root=root, client=docker_client(), env=env, proc=proc)
    deadline = time.monotonic() + timeout
    while True:
        if proc.poll() is not None:
            stop_engine(engine)
            raise DockerSetupError(f"dockerd exited {proc.returncode}:\n{_tail(p['log'])}")
        ping = engine.docker("version", "--format", "{{.Server.Version}}", check=False, timeout=10)
        if ping.returncode == 0:
            break
        if time.monotonic() > deadline:
            stop_engine(engine)
            raise DockerSetupError(f"dockerd not answering after {timeout} s:\n{_tail(p['log'])}")
        time.sleep(0.25)
    # What an interrupted run left in this engine (stopped containers, their volumes and
    # networks) is of no use; images stay: they are the cache.
    for kind in ("container", "volume", "network"):
        engine.docker(kind, "prune", "--force", check=False, timeout=120)
    engine.timings["engine_start_s"] = round(time.monotonic() - t0, 1)
    return engine


def stop_engine(engine: Engine, timeout: float = 30.0) -> list[str]:
    """Stop dockerd (and its containerd) and clean the host; returns what was cleaned."""
    t0 = time.monotonic()
    proc = engine.proc
    if proc is not None and proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
    actions = clean_host(engine.root)
    engine.timings["engine_stop_s"] = round(time.monotonic() - t0, 1)
    return actions


def _tail(path: Path, n: int = 30) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-n:])
    except OSError:
        return "(no log)"


# --------------------------------------------------------------------------- the base image


def base_image_ref(codename: str) -> str:
    h = hashlib.sha256(BASE_RECIPE.encode())
    h.update(codename.encode())
    if HOST_CA_BUNDLE.is_file():
        h.update(HOST_CA_BUNDLE.read_bytes())
    return f"local/{codename}-python:{h.hexdigest()[:12]}"


def ensure_base_image(engine: Engine) -> str:
    """``local/<codename>-python:<key>``: in the engine already, else imported from the cached
    rootfs tarball, else made with debootstrap (and the tarball kept)."""
    codename = host_codename()
    ref = base_image_ref(codename)
    if engine.image_exists(ref):
        engine.timings["base_image"] = "cached image"
        return ref
    tag = ref.split(":", 1)[1]
    base_dir = engine.root / "base"
    tarball = base_dir / f"{codename}-python-{tag}.tar"
    if not tarball.is_file():
        t0 = time.monotonic()
        _debootstrap(codename, base_dir, tarball)
        engine.timings["base_debootstrap_s"] = round(time.monotonic() - t0, 1)
    t0 = time.monotonic()
    ca = BASE_CA_FILE
    changes = [
        "ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin",
        "ENV LANG=C.UTF-8",
        *(
            [f"ENV SSL_CERT_FILE={ca}", f"ENV PIP_CERT={ca}", f"ENV REQUESTS_CA_BUNDLE={ca}"]
            if HOST_CA_BUNDLE.is_file()
            else []
        ),
        'CMD ["/bin/bash"]',
    ]
    args = [a for c in changes for a in ("--change", c)]
    engine.docker("import", *args, str(tarball), ref, timeout=300)
    engine.timings["base_import_s"] = round(time.monotonic() - t0, 1)
    engine.timings.setdefault("base_image", "imported from cached tarball")
    if "base_debootstrap_s" in engine.timings:
        engine.timings["base_image"] = "built with debootstrap"
    return ref


def _debootstrap(codename: str, base_dir: Path, tarball: Path) -> None:
    mirror, source = debian_mirror(codename)
    base_dir.mkdir(parents=True, exist_ok=True)
    for old in base_dir.glob(f"{codename}-python-*.tar"):
        old.unlink()  # another recipe or CA: superseded
    rootfs = Path(tempfile.mkdtemp(prefix="rootfs-", dir=base_dir))
    try:
        proc = _run(
            [
                "debootstrap",
                "--variant=minbase",
                f"--include={','.join(BASE_PACKAGES)}",
                codename,
                str(rootfs),
                mirror,
            ],
            timeout=900,
            check=False,
        )
        if proc.returncode != 0:
            # The mirror's address stays out of the message (it may be logged or kept).
            log = rootfs / "debootstrap" / "debootstrap.log"
            detail = _tail(log, 15) if log.exists() else proc.stderr[-1500:]
            raise DockerSetupError(
                f"debootstrap {codename} (mirror from {source}) failed ({proc.returncode}):\n"
                + detail.replace(mirror, "<mirror>")
            )
        # Nothing of this machine's but its CA bundle goes into the image: no apt sources
        # (they name the mirror), no resolv.conf or hostname, no package caches.
        for rel in (
            "etc/apt/sources.list",
            "etc/resolv.conf",
            "etc/hostname",
            "var/log/bootstrap.log",
        ):
            (rootfs / rel).unlink(missing_ok=True)
        for pattern in ("var/lib/apt/lists/*", "var/cache/apt/*.bin", "var/cache/apt/archives/*"):
            for f in rootfs.glob(pattern):
                if f.is_file():
                    f.unlink()
        if HOST_CA_BUNDLE.is_file():
            for dest in (rootfs / str(HOST_CA_BUNDLE)[1:], rootfs / BASE_CA_FILE[1:]):
                dest.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(HOST_CA_BUNDLE, dest)
        partial = tarball.with_suffix(".tar.partial")
        _run(
            ["tar", "--numeric-owner", "--xattrs", "-C", str(rootfs), "-cf", str(partial), "."],
            timeout=300,
        )
        partial.rename(tarball)
    finally:
        _unmount_under(rootfs)
        shutil.rmtree(rootfs, ignore_errors=True)


# --------------------------------------------------------------------------- the project image


def pip_build_args() -> list[str]:
    """``--build-arg`` for how this host reaches its package index and the Internet, read now:
    pip's index URLs (environment first, then ``pip config``) when they are network URLs — a
    ``file://`` index or ``--find-links`` directory is on the host's disk and means nothing in a
    build — and the proxy variables, each only if set. The values go to the engine, never to a
    file."""
    values: dict[str, str] = {}
    config: dict[str, str] = {}
    proc = _run([sys.executable, "-m", "pip", "config", "list"], check=False, timeout=60)
    for line in proc.stdout.splitlines():
        key, _, value = line.partition("=")
        config[key.strip()] = value.strip().strip("'\"")
    for var, keys in (
        ("PIP_INDEX_URL", ("global.index-url", "install.index-url")),
        ("PIP_EXTRA_INDEX_URL", ("global.extra-index-url", "install.extra-index-url")),
    ):
        raw = os.environ.get(var) or next((config[k] for k in keys if k in config), "")
        urls = [u for u in raw.split() if u.startswith(("http://", "https://"))]
        if urls:
            values[var] = " ".join(urls)
    if os.environ.get("PIP_DEFAULT_TIMEOUT"):
        values["PIP_DEFAULT_TIMEOUT"] = os.environ["PIP_DEFAULT_TIMEOUT"]
    for var in ("HTTP_PROXY", "HTTPS_PROXY", "NO_PROXY", "ALL_PROXY"):
        for name in (var, var.lower()):
            if os.environ.get(name):
                values[name] = os.environ[name]
    return [a for k, v in values.items() for a in ("--build-arg", f"{k}={v}")]


def build_project_image(engine: Engine, base: str, tag: str = PROJECT_IMAGE) -> str:
    """Build ``docker/Dockerfile`` on ``base``; old copies of ``tag`` are pruned afterwards
    (the layers the new image shares with them, such as the dependencies, stay cached)."""
    t0 = time.monotonic()
    proc = engine.docker(
        "build",
        "--file",
        str(REPO / "docker" / "Dockerfile"),
        "--build-arg",
        f"BASE_IMAGE={base}",
        *pip_build_args(),
        "--tag",
        tag,
        str(REPO),
        timeout=1200,
        check=False,
    )
    engine.timings["project_build_s"] = round(time.monotonic() - t0, 1)
    # Hosts (a mirror, an index, a proxy) stay out of the kept log and of the message.
    log = redact_hosts(proc.stdout + proc.stderr)
    (engine.root / "build.log").write_text(log)
    if proc.returncode != 0:
        raise DockerSetupError(
            f"docker build failed ({proc.returncode}); full log in {engine.root}/build.log:\n"
            + log[-4000:]
        )
    engine.timings["project_build_cached_steps"] = proc.stdout.count("Using cache")
    engine.docker("image", "prune", "--force", "--filter", "dangling=true", timeout=300)
    remove_stale_bases(engine, keep=base)
    return tag


def remove_stale_bases(engine: Engine, keep: str) -> None:
    """Bases of an older recipe or CA bundle that no image uses any more."""
    repo = keep.split(":", 1)[0]
    listing = engine.docker("image", "ls", repo, "--format", "{{.Repository}}:{{.Tag}}")
    for ref in listing.stdout.split():
        if ref != keep:
            engine.docker("image", "rm", ref, check=False, timeout=120)


def redact_hosts(text: str) -> str:
    """``scheme://<host>/path`` for every URL in ``text``, and ``host='<host>'`` (urllib3)."""
    text = re.sub(r"\b([a-z][a-z0-9+.-]*://)[^/\s'\"]+", r"\1<host>", text)
    return re.sub(r"\bhost=(['\"])[^'\"]*\1", "host='<host>'", text)


def prepare() -> dict[str, object]:
    """Make the base image and build the project's image into the cache, then stop the
    engine: what the smoke test then finds ready (``make test`` runs this beside the parallel
    tests, so the image's build is not on the serial part's clock)."""
    ensure_prerequisites()
    root = cache_dir()
    with engine_lock(root):
        engine = start_engine(root)
        try:
            build_project_image(engine, ensure_base_image(engine))
        finally:
            engine.timings["cleaned"] = stop_engine(engine)
    return engine.timings


def main(argv: Sequence[str] | None = None) -> int:
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m testing.docker", description="the Docker smoke test's engine and images"
    )
    parser.add_argument("command", choices=["prepare"], help="build the images into the cache")
    parser.parse_args(argv)
    t0 = time.monotonic()
    try:
        timings = prepare()
    except DockerSetupError as exc:
        print(f"testing.docker prepare: {exc}", file=sys.stderr)
        return 1
    print(json.dumps({**timings, "prepare_s": round(time.monotonic() - t0, 1)}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
