#!/usr/bin/env python3
"""Builds the fuzz targets for libFuzzer and fuzzes each one for a while.

What `cmake --build BUILD --target fuzz-long` runs (tests/fuzz/README.md).
It configures a tree of its own under WORK/build with clang, every file
compiled with -fsanitize=fuzzer-no-link,address,undefined -O1 and the fuzz
targets linked with -fsanitize=fuzzer (the project's CVRE_LIBFUZZER
option), builds the targets, then runs them one after the other, each on a
fresh copy of its committed corpus (WORK/<target>/corpus) for SECONDS, in
libFuzzer's fork mode with JOBS workers (one core by default) so that a
crash is recorded (WORK/<target>/artifacts) and fuzzing goes on. Last, one
line per target: executions per second, libFuzzer's coverage (cov: edges,
ft: features), corpus size and crashes.

Exits 0 if every target built and none crashed, leaked, ran out of memory
or timed out; 1 otherwise.

Environment: FUZZ_SECONDS (seconds per target) overrides --seconds,
FUZZ_TARGETS (space-separated names) the targets, FUZZ_JOBS --jobs.
"""
import argparse
import os
import re
import shutil
import subprocess
import sys

# libFuzzer flags for every target. Inputs up to 128 KiB (the corpus files
# are under 32 KiB; the rest is room to grow), 10 s an input (Assimp
# triangulating a 10,000-gon twice under ASan takes a few), 4 GB of memory
# (the importer's limits allow ~0.5 GB, ASan doubles it).
FLAGS = ['-max_len=131072', '-timeout=10', '-rss_limit_mb=4096', '-malloc_limit_mb=4096',
         '-print_final_stats=1']

COMPILE = '-g -O1 -fno-omit-frame-pointer -fsanitize=fuzzer-no-link,address,undefined ' \
          '-fno-sanitize-recover=all'


def build(source, tree, targets, log):
    """Configures and builds; returns the targets that built."""
    cmd = ['cmake', '-S', source, '-B', tree, '-DCMAKE_C_COMPILER=clang', '-DCMAKE_BUILD_TYPE=FuzzLong',
           '-DCMAKE_C_FLAGS=' + COMPILE, '-DCVRE_LIBFUZZER=ON']
    with open(log, 'w') as out:
        if subprocess.run(cmd, stdout=out, stderr=subprocess.STDOUT).returncode != 0:
            return []
        built = []
        for t in targets:
            r = subprocess.run(['cmake', '--build', tree, '--target', t, '-j', str(os.cpu_count() or 1)],
                               stdout=out, stderr=subprocess.STDOUT)
            if r.returncode == 0:
                built.append(t)
    return built


def find_binary(tree, target):
    for d in ('tests', '.'):
        p = os.path.join(tree, d, target)
        if os.path.isfile(p):
            return p
    return None


def last_status(log):
    """The numbers of libFuzzer's last status line (fork or plain mode)."""
    stats = {}
    with open(log, errors='replace') as f:
        for line in f:
            if 'cov:' in line and 'ft:' in line:
                for key, pat in (('cov', r'cov: (\d+)'), ('ft', r'ft: (\d+)'),
                                 ('execs', r'^#(\d+)'), ('exec_s', r'exec/s:? (\d+)'),
                                 ('faults', r'oom/timeout/crash: (\d+/\d+/\d+)'), ('time', r'time: (\d+)s')):
                    m = re.search(pat, line)
                    if m:
                        stats[key] = m.group(1)
            m = re.match(r'stat::number_of_executed_units: (\d+)', line)
            if m:
                stats['execs'] = m.group(1)
    return stats


def run(binary, target, source, work, seconds, jobs):
    """Fuzzes one target; returns its figures."""
    home = os.path.join(work, target)
    corpus, artifacts = os.path.join(home, 'corpus'), os.path.join(home, 'artifacts')
    shutil.rmtree(home, ignore_errors=True)
    shutil.copytree(os.path.join(source, 'tests', 'fuzz', 'corpus', target), corpus)
    os.makedirs(artifacts)
    log = os.path.join(home, 'fuzz.log')
    cmd = [binary, f'-max_total_time={seconds}', f'-fork={jobs}', '-ignore_crashes=1', '-ignore_ooms=1',
           '-ignore_timeouts=1', '-artifact_prefix=' + artifacts + '/'] + FLAGS + [corpus]
    env = dict(os.environ, UBSAN_OPTIONS='print_stacktrace=1:halt_on_error=1')
    print(f'fuzz-long: {target}: {seconds} s, log {log}', flush=True)
    with open(log, 'w') as out:
        out.write(' '.join(cmd) + '\n')
        out.flush()
        rc = subprocess.run(cmd, stdout=out, stderr=subprocess.STDOUT, cwd=home, env=env).returncode
    s = last_status(log)
    files = os.listdir(corpus)
    s['corpus'] = len(files)
    s['corpus_bytes'] = sum(os.path.getsize(os.path.join(corpus, f)) for f in files)
    found = sorted(f for f in os.listdir(artifacts) if re.match(r'(crash|leak|oom|timeout|slow-unit)-', f))
    s['artifacts'] = [f for f in found if not f.startswith('slow-unit')]
    s['rc'] = rc
    if 'execs' in s and s.get('time'):  # over the whole run, not libFuzzer's last job
        s['exec_s'] = str(int(s['execs']) // max(1, int(s['time'])))
    return s


def main():
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--source', required=True, help='the repository')
    p.add_argument('--work', required=True, help='where the build, corpora and logs go')
    p.add_argument('--seconds', type=int, default=600, help='per target (FUZZ_SECONDS)')
    p.add_argument('--jobs', type=int, default=1, help='fork-mode workers (FUZZ_JOBS)')
    p.add_argument('targets', nargs='*', help='fuzz_proto fuzz_glb... (FUZZ_TARGETS)')
    a = p.parse_args()
    seconds = int(os.environ.get('FUZZ_SECONDS', a.seconds))
    jobs = int(os.environ.get('FUZZ_JOBS', a.jobs))
    targets = os.environ.get('FUZZ_TARGETS', '').split() or a.targets
    if not targets:
        p.error('no targets')
    work = os.path.abspath(a.work)
    os.makedirs(work, exist_ok=True)
    tree = os.path.join(work, 'build')
    build_log = os.path.join(work, 'build.log')
    print(f'fuzz-long: building {" ".join(targets)} with clang and libFuzzer (log {build_log})', flush=True)
    built = build(os.path.abspath(a.source), tree, targets, build_log)
    results = {}
    for t in targets:
        binary = find_binary(tree, t) if t in built else None
        if binary:
            results[t] = run(binary, t, os.path.abspath(a.source), work, seconds, jobs)
    bad = 0
    print(f'\nfuzz-long: {seconds} s per target, {jobs} job(s); cov and ft as libFuzzer last counted them')
    print(f'{"target":12} {"execs":>9} {"execs/s":>8} {"cov":>6} {"ft":>7} {"corpus":>15} {"crashes":>8}  notes')
    for t in targets:
        if t not in results:
            print(f'{t:12} could not be built (see {build_log}; libFuzzer on Debian: libclang-rt-14-dev)')
            bad = 1
            continue
        s = results[t]
        n = len(s['artifacts'])
        note = ''
        if n:
            note = f'{os.path.join(work, t, "artifacts")}: {" ".join(s["artifacts"][:4])}'
            bad = 1
        elif s['rc'] != 0:
            note = f'libFuzzer exited {s["rc"]}: see {os.path.join(work, t, "fuzz.log")}'
            bad = 1
        corpus = f'{s["corpus"]} ({s["corpus_bytes"] // 1024} KiB)'
        print(f'{t:12} {s.get("execs", "?"):>9} {s.get("exec_s", "?"):>8} {s.get("cov", "?"):>6} '
              f'{s.get("ft", "?"):>7} {corpus:>15} {n:>8}  {note}')
    return bad


if __name__ == '__main__':
    sys.exit(main())
