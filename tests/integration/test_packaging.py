"""Packaging, checked where no container engine runs: `cmake --install` into
a temporary prefix yields the five programs, each with its --help, the
systemd unit (valid for systemd-analyze where it is installed) and the
sysusers entry, and the installed server imports a world through the
cvre-import installed beside it, and serves the installed browser client
(every file its page loads, found by following its imports).
docker/Dockerfile builds with
tools/deps.sh's packages, installs at run time exactly the Debian packages
whose libraries the built programs link (ldd, dpkg -S; what those link in
turn must come with them through the packages' dependencies), copies
programs that the install makes, and its default world finds every model
where the image puts them. The package relations are this machine's: the
Debian 12 that tools/deps.sh provisions."""
import json
import os
import urllib.error
import urllib.request
import posixpath
import re
import shlex
import shutil
import subprocess
import tempfile
import time

from harness import TEMP_DIRS, Server, args, run

A = args()
ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
DOCKER = os.path.join(ROOT, "docker")
PROGRAMS = ["cvre-server", "cvre-import", "cvre-client", "cvre-admin", "cvre-cluster"]
WORLD = os.path.join(ROOT, "tests", "integration", "room.world")
# Packages tools/deps.sh installs that the image's build stage leaves out:
# only the test suite needs them.
TEST_ONLY = {"chromium"}


# ---- the Dockerfile ----------------------------------------------------------

def instructions(path):
    """The Dockerfile's instructions as (stage index, KEYWORD, text), with
    continuation lines joined and comment lines dropped, as Docker does."""
    out, stage, pending = [], -1, ""
    for line in open(path):
        if line.lstrip().startswith("#"):  # also inside a continued instruction
            continue
        line = line.rstrip("\n")
        if line.endswith("\\"):
            pending += line[:-1] + " "
            continue
        text = (pending + line).strip()
        pending = ""
        if not text:
            continue
        word, _, rest = text.partition(" ")
        word = word.upper()
        if word == "FROM":
            stage += 1
        out.append((stage, word, rest.strip()))
    assert not pending, "a continued line runs off the end"
    return out


def apt_packages(text):
    """The packages of every `apt-get install` in a RUN's text."""
    found = []
    for part in text.split("&&"):
        words = shlex.split(part)
        if "apt-get" in words and "install" in words:
            found += [w for w in words[words.index("install") + 1:] if not w.startswith("-")]
    return found


def deps_sh_packages():
    """tools/deps.sh's packages: its list, and Node.js with npm (which it
    installs from Debian where no npm is on the PATH; the image has none)."""
    text = open(os.path.join(ROOT, "tools", "deps.sh")).read()
    found = set()
    for name in ("packages", "node_packages"):
        m = re.search(r"^" + name + r"=\((.*?)\)", text, re.S | re.M)
        assert m, f"tools/deps.sh has no {name}=(...) list"
        found |= set(m.group(1).split())
    return found


class Dockerfile:
    def __init__(self):
        self.ins = instructions(os.path.join(DOCKER, "Dockerfile"))
        stages = max(s for s, _, _ in self.ins) + 1
        assert stages == 2, f"expected a build stage and a runtime stage, found {stages}"

    def of(self, stage, word):
        return [t for s, w, t in self.ins if s == stage and w == word]

    def apt(self, stage):
        return [p for t in self.of(stage, "RUN") for p in apt_packages(t)]


# ---- libraries and packages ----------------------------------------------------

def needed(binary):
    """The DT_NEEDED sonames of a binary."""
    out = subprocess.run(["readelf", "-d", binary], capture_output=True, text=True, check=True).stdout
    return re.findall(r"\(NEEDED\)\s+Shared library: \[(.+?)\]", out)


def ldd(binary):
    """soname -> path of every library the binary loads, transitively."""
    out = subprocess.run(["ldd", binary], capture_output=True, text=True, check=True).stdout
    libs = {}
    for line in out.splitlines():
        m = re.match(r"\s*(\S+) => (/\S+)", line)
        if m:
            libs[m.group(1)] = m.group(2)
        else:
            m = re.match(r"\s*(/\S+) \(", line)  # the dynamic loader
            if m:
                libs[os.path.basename(m.group(1))] = m.group(1)
    return libs


def path_variants(path):
    """The names dpkg may know a library under (merged /usr: /lib or
    /usr/lib, the link or its target)."""
    out = []
    for p in (path, os.path.realpath(path)):
        out += [p, p[4:] if p.startswith("/usr/") else "/usr" + p]
    return out


def packages_of(paths):
    """path -> the Debian package that ships it, for every path (one dpkg -S
    for all: each call reads dpkg's whole database)."""
    variants = {v: p for p in paths for v in path_variants(p)}
    r = subprocess.run(["dpkg", "-S", *variants], capture_output=True, text=True)
    found = {}
    for line in r.stdout.splitlines():
        pkg, _, shipped = line.partition(": ")
        if shipped in variants:
            found.setdefault(variants[shipped], pkg.split(",")[0].split(":")[0].strip())
    lost = sorted(set(paths) - set(found))
    assert not lost, f"no Debian package ships {lost}"
    return found


def installed_packages():
    """name -> (essential, [dependency groups]) of every installed package;
    a group is a list of alternatives (Depends and Pre-Depends)."""
    out = subprocess.run(["dpkg-query", "-W", "-f", "${Package}\t${Essential}\t${Pre-Depends}\t${Depends}\n"],
                         capture_output=True, text=True, check=True).stdout
    pkgs = {}
    for line in out.splitlines():
        name, essential, pre, dep = (line.split("\t") + ["", "", ""])[:4]
        groups = []
        for field in (pre, dep):
            for group in filter(None, (g.strip() for g in field.split(","))):
                groups.append([re.split(r"[\s(:]", alt.strip(), 1)[0] for alt in group.split("|")])
        pkgs[name] = (essential == "yes", groups)
    return pkgs


def closure(start, pkgs):
    """start and every package its dependencies bring (the first installed
    alternative of each group)."""
    seen, todo = set(), list(start)
    while todo:
        p = todo.pop()
        if p in seen or p not in pkgs:
            continue
        seen.add(p)
        for group in pkgs[p][1]:
            alt = next((a for a in group if a in pkgs), None)
            if alt:
                todo.append(alt)
    return seen


# ---- the browser client ------------------------------------------------------------

# A static import (import x from '...', import '...') or re-export (export
# * from '...', export { a } from '...').
IMPORT = re.compile(r"""^\s*(?:import\s+(?:[\w*{}\s,$]+\s+from\s*)?|export\s+(?:\*|\{[^}]*\})\s*from\s*)['"]([^'"]+)['"]""",
                    re.M)


def page_files(base):
    """Every path the web client's page at base loads: index.html, its
    stylesheet and script, and each module's static imports in turn (bare
    names through the page's import map), with the status and content type
    each was served with."""
    html = urllib.request.urlopen(base + "/", timeout=10).read().decode()
    imap = json.loads(re.search(r'<script type="importmap">(.*?)</script>', html, re.S).group(1))["imports"]
    todo = ["/" + p for p in re.findall(r'(?:href|src)="([^":]+)"', html)]
    seen = {}
    while todo:
        path = posixpath.normpath(todo.pop())
        if path in seen:
            continue
        try:
            r = urllib.request.urlopen(base + path, timeout=10)
            seen[path] = (r.status, r.headers.get("Content-Type", ""))
            body = r.read().decode()
        except urllib.error.HTTPError as e:
            seen[path] = (e.code, "")
            continue
        if not path.endswith(".js"):
            continue
        for spec in IMPORT.findall(body):
            bare = next((k for k in sorted(imap, key=len, reverse=True)
                         if spec == k or (k.endswith("/") and spec.startswith(k))), None)
            if bare:
                todo.append(posixpath.join("/", imap[bare].lstrip("./") + spec[len(bare):]))
            else:
                todo.append(posixpath.join(posixpath.dirname(path), spec))
    return seen


# ---- tests -----------------------------------------------------------------------

def install(prefix):
    r = subprocess.run(["cmake", "--install", A.bin, "--prefix", prefix], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    return prefix


def test_install_yields_the_programs_the_unit_and_a_working_layout():
    prefix = install(tempfile.mkdtemp(prefix="cvre-install-"))
    TEMP_DIRS.append(prefix)
    bindir = os.path.join(prefix, "bin")
    assert sorted(os.listdir(bindir)) == sorted(PROGRAMS), os.listdir(bindir)
    for p in PROGRAMS:
        r = subprocess.run([os.path.join(bindir, p), "--help"], capture_output=True, text=True, timeout=30)
        assert r.returncode == 0 and r.stdout.startswith(f"usage: {p}"), (p, r.returncode, r.stdout[:200])
        assert re.search(r"^\s+--help\b|--help,", r.stdout, re.M), (p, "no --help in its options")
        r = subprocess.run([os.path.join(bindir, p), "--version"], capture_output=True, text=True, timeout=30)
        assert r.returncode == 0 and r.stdout.startswith(p + " "), (p, r.stdout)
    unit = os.path.join(prefix, "lib", "systemd", "system", "cvre-server.service")
    text = open(unit).read()
    assert re.search(r"^ExecStart=" + re.escape(os.path.join(bindir, "cvre-server")) + " ", text, re.M), text
    for line in ("User=cvre", "StateDirectory=cvre", "NoNewPrivileges=yes", "SystemCallFilter=@system-service seccomp"):
        assert re.search("^" + re.escape(line) + "$", text, re.M), line
    assert "/var/lib/cvre/cvre.db" in text
    sysusers = open(os.path.join(prefix, "lib", "sysusers.d", "cvre.conf")).read()
    assert re.search(r"^u cvre - .* /var/lib/cvre$", sysusers, re.M), sysusers
    if shutil.which("systemd-analyze"):
        r = subprocess.run(["systemd-analyze", "verify", unit], capture_output=True, text=True, timeout=60)
        assert r.returncode == 0 and not r.stdout.strip() and not r.stderr.strip(), r.stdout + r.stderr
    else:
        print("     (systemd-analyze not installed: the unit's syntax is not verified)")
    # The installed server finds the installed cvre-import beside it.
    # ... and serves the installed browser client: everything its page loads.
    webroot = os.path.join(prefix, "share", "cvre", "web")
    srv = Server(bindir, "--world", WORLD, "--refine-interval", "0", "--web", "127.0.0.1:0", "--web-root", webroot)
    m = re.search(r"web on (http://127\.0\.0\.1:\d+)/", srv.logtext())
    assert m, srv.logtext()
    files = page_files(m.group(1))
    types = {".html": "text/html", ".js": "text/javascript", ".css": "text/css"}
    for path, (status, ctype) in files.items():
        assert status == 200 and ctype.startswith(types[posixpath.splitext(path)[1]]), (path, status, ctype)
    for want in ("/src/main.js", "/node_modules/three/build/three.module.js", "/node_modules/three/build/three.core.js"):
        assert want in files, (want, sorted(files))
    assert srv.stop() == 0
    assert "1 objects loaded from 1 model files" in srv.logtext(), srv.logtext()


def test_docker_build_stage_mirrors_deps_sh():
    d = Dockerfile()
    build = d.apt(0)
    assert len(build) == len(set(build)), f"a package twice: {build}"
    want = deps_sh_packages() - TEST_ONLY
    assert set(build) == want, (f"docker/Dockerfile's build packages differ from tools/deps.sh's: missing "
                                f"{sorted(want - set(build))}, extra {sorted(set(build) - want)}")
    run_text = " ".join(d.of(0, "RUN"))
    m = re.search(r"--target ((?:[\w-]+ ?)+)", run_text)
    built = set(m.group(1).split()) if m else set()
    assert set(PROGRAMS) <= built, f"the build stage does not build {sorted(set(PROGRAMS) - built)}"
    assert re.search(r"DESTDIR=\S+ cmake --install \S+ --prefix \S+", run_text), run_text


def test_docker_runtime_packages_are_what_the_programs_link():
    d = Dockerfile()
    listed = d.apt(1)
    assert len(listed) == len(set(listed)), f"a package twice: {listed}"
    pkgs = installed_packages()
    base = closure({p for p, (ess, _) in pkgs.items() if ess} | {"apt"}, pkgs)  # debian:12 (minbase) has these
    direct, everything, resolved = {}, {}, {}
    for p in PROGRAMS:
        path = os.path.join(A.bin, p)
        libs = ldd(path)
        resolved[p] = (libs, needed(path))
    owner = packages_of({lib for libs, _ in resolved.values() for lib in libs.values()})
    for p, (libs, sonames) in resolved.items():
        for soname in sonames:
            assert soname in libs, f"{p}: ldd does not resolve {soname}"
            direct.setdefault(owner[libs[soname]], set()).add(f"{soname} ({p})")
        for soname, lib in libs.items():
            everything.setdefault(owner[lib], set()).add(f"{soname} ({p})")
    missing = sorted(set(direct) - set(listed) - base)
    extra = sorted(set(listed) - set(direct))
    assert not missing, "docker/Dockerfile's runtime stage lacks " + "; ".join(
        f"{k} (for {', '.join(sorted(direct[k]))})" for k in missing)
    assert not extra, f"docker/Dockerfile's runtime stage installs {extra}, which no program links"
    brought = closure(set(listed), pkgs) | base
    unbrought = sorted(set(everything) - brought)
    assert not unbrought, "installing the runtime packages would not bring " + "; ".join(
        f"{k} (for {', '.join(sorted(everything[k]))})" for k in unbrought)


def image_paths(d):
    """Image directory -> host directory, from the runtime stage's COPY
    lines: the build context (the repository), the models context (as the
    compose file names it, relative to docker/), the build stage's install
    (a temporary `cmake --install` of this tree)."""
    compose = open(os.path.join(DOCKER, "compose.yaml")).read()
    m = re.search(r"additional_contexts:\s*\n\s*models:\s*(\S+)", compose)
    assert m, "compose.yaml gives no models context"
    models = os.path.normpath(os.path.join(DOCKER, m.group(1)))
    header = open(os.path.join(DOCKER, "Dockerfile")).read()
    m = re.search(r"--build-context models=(\S+)", header)
    assert m and os.path.normpath(os.path.join(ROOT, m.group(1))) == models, \
        "the Dockerfile's build command and compose.yaml name different model directories"
    build_run = " ".join(d.of(0, "RUN"))
    m = re.search(r"DESTDIR=(\S+) cmake --install \S+ --prefix (\S+)", build_run)
    stage_root = posixpath.join(m.group(1), m.group(2).lstrip("/"))
    prefix = install(tempfile.mkdtemp(prefix="cvre-install-"))
    TEMP_DIRS.append(prefix)
    paths = {}
    for text in d.of(1, "COPY"):
        words = shlex.split(text)
        src_from = next((w.split("=", 1)[1] for w in words if w.startswith("--from=")), None)
        src, dst = [w for w in words if not w.startswith("--")]
        if src_from == "build":
            assert src.startswith(stage_root), f"COPY {src}: not from the install ({stage_root})"
            host = os.path.join(prefix, os.path.relpath(src, stage_root))
        elif src_from == "models":
            host = os.path.join(models, src)
        else:
            assert src_from is None, f"COPY from an unknown stage or context: {text}"
            host = os.path.join(ROOT, src)
        assert os.path.exists(host), f"COPY {text}: {host} does not exist"
        paths[dst.rstrip("/") or "/"] = os.path.normpath(host)
    return paths, prefix


def host_path(paths, image_path):
    for dst in sorted(paths, key=len, reverse=True):
        if image_path == dst or image_path.startswith(dst + "/"):
            return os.path.join(paths[dst], os.path.relpath(image_path, dst))
    return None


def test_docker_runtime_stage_has_programs_world_and_health():
    d = Dockerfile()
    paths, prefix = image_paths(d)
    bin_host = host_path(paths, "/usr/local/bin")
    assert bin_host and sorted(os.listdir(bin_host)) == sorted(PROGRAMS), paths
    entry = json.loads(d.of(1, "ENTRYPOINT")[0])
    cmd = json.loads(d.of(1, "CMD")[0])
    assert entry[0] in PROGRAMS and entry[0] == "cvre-server", entry
    argv = entry + cmd
    flags = {argv[i]: argv[i + 1] for i in range(1, len(argv) - 1) if argv[i].startswith("--")}
    volumes = " ".join(d.of(1, "VOLUME")).split()
    assert any(flags["--db"].startswith(v.rstrip("/") + "/") for v in volumes), (flags, volumes)
    exposed = " ".join(d.of(1, "EXPOSE")).split()
    metrics_port = flags["--metrics"].rsplit(":", 1)[1]
    web_port = flags["--web"].rsplit(":", 1)[1]
    assert flags["--port"] in exposed and metrics_port in exposed and web_port in exposed, (flags, exposed)
    webroot = host_path(paths, flags["--web-root"])
    assert webroot and os.path.samefile(webroot, os.path.join(prefix, "share", "cvre", "web")), \
        f"--web-root {flags['--web-root']} is not the installed browser client: {paths}"
    health = d.of(1, "HEALTHCHECK")
    assert health and f"/dev/tcp/127.0.0.1/{metrics_port}" in health[0], f"the health check asks another port: {health}"
    # The check itself, against this build's server: healthy while it runs, not once it stopped.
    probe = json.loads(health[0].split(" CMD ", 1)[1])
    srv = Server(A.bin, "--metrics", "127.0.0.1:0", "--refine-interval", "0")
    end = time.time() + 30
    while not re.search(r"metrics on http://127\.0\.0\.1:(\d+)/", srv.logtext()):
        assert time.time() < end, "the server logged no metrics address"
        time.sleep(0.1)
    port = re.search(r"metrics on http://127\.0\.0\.1:(\d+)/", srv.logtext()).group(1)
    probe = [w.replace(f"/127.0.0.1/{metrics_port}", f"/127.0.0.1/{port}") for w in probe]
    assert subprocess.run(probe, capture_output=True, timeout=30).returncode == 0, probe
    assert srv.stop() == 0
    assert subprocess.run(probe, capture_output=True, timeout=30).returncode != 0, "healthy without a server"
    # The default world, and every model it names, where the server looks.
    world_image = flags["--world"]
    world = host_path(paths, world_image)
    assert world and os.path.isfile(world), f"the default world {world_image} is not in the image: {paths}"
    objects = 0
    for line in open(world):
        words = line.split()
        if words[:1] != ["object"]:
            continue
        image_model = posixpath.normpath(posixpath.join(posixpath.dirname(world_image), words[1]))
        host = host_path(paths, image_model)
        assert host and os.path.isfile(host), f"{world_image} names {image_model}, which the image lacks"
        objects += 1
    assert objects >= 5, objects
    # compose: the bots run a program of the image, once the server is healthy.
    compose = open(os.path.join(DOCKER, "compose.yaml")).read()
    for prog in re.findall(r'entrypoint: \["([\w-]+)"', compose):
        assert prog in PROGRAMS, prog
    assert "condition: service_healthy" in compose


run([test_install_yields_the_programs_the_unit_and_a_working_layout, test_docker_build_stage_mirrors_deps_sh,
     test_docker_runtime_packages_are_what_the_programs_link, test_docker_runtime_stage_has_programs_world_and_health])
