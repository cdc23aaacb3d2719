#!/usr/bin/env python3
"""The work of scripts/ci/crash-safety.sh (read its header first).

kill -9s a `treemorph serve` (SQLite and local blobs in one data directory,
the test runner) again and again while clients upload trees, generate trees,
post jobs, cancel jobs, render frames at instants of succeeded jobs and
delete ended jobs (a delete timed to race each kill); then restarts it once more, lets every job finish
and checks that nothing acknowledged was lost, that everything served is
complete and that the database is intact. Standard library only. Exits 1
with a list of the failed assertions.
"""

import argparse
import datetime
import hashlib
import http.client
import json
import os
import random
import signal
import sqlite3
import struct
import subprocess
import sys
import threading
import time
import urllib.parse
import zlib

KILLS = 20
FRAMES = 16  # frames per job; with MS_PER_FRAME a job runs about 1.6 s
MS_PER_FRAME = 100
FINAL_MS_PER_FRAME = 10  # the last run drains the backlog quickly
KILL_AFTER_S = (0.3, 3.0)  # uniform: how long each server lives
JOBS_PER_LIFE = 3
UPLOADERS = 2
UPLOAD_CHUNK = 64 * 1024
UPLOAD_CHUNK_PAUSE_S = 0.01  # about 0.5-0.7 s per upload body
FINISH_DEADLINE_S = 90
MIN_KILLS_DURING_UPLOAD = 5
MIN_ATTEMPTS_CUT = 5
MIN_KILLS_DURING_RENDER = 5
RENDER_JOBS = 2  # run to success before the first kill (start_render_jobs)
MIN_DELETES_DONE = 5
TERMINAL = {"succeeded", "failed", "cancelled"}
MAX_ATTEMPTS = 3  # the server's default --max-attempts

failures = []


def log(msg):
    print(msg, flush=True)


def check(ok, msg):
    if not ok:
        failures.append(msg)
        if len(failures) <= 50:
            log(f"FAIL: {msg}")
    return ok


# --- HTTP -------------------------------------------------------------------


class Response:
    def __init__(self, status, headers, body):
        self.status, self.headers, self.body = status, headers, body

    def json(self):
        return json.loads(self.body)


def request(base, method, path, body=None, headers=None, timeout=15, on_sent=None,
            chunk_pause=0.0):
    """One request on a fresh connection. With `chunk_pause` the body goes out
    in UPLOAD_CHUNK pieces with a pause after each (a slow upload);
    `on_sent` is called once the body is out. Raises OSError/HTTPException
    when the server goes away; a short body raises IncompleteRead."""
    u = urllib.parse.urlsplit(base)
    conn = http.client.HTTPConnection(u.hostname, u.port, timeout=timeout)
    try:
        conn.putrequest(method, path)
        for k, v in (headers or {}).items():
            conn.putheader(k, v)
        if body is not None:
            conn.putheader("Content-Length", str(len(body)))
        conn.endheaders()
        if body is not None:
            if chunk_pause:
                for i in range(0, len(body), UPLOAD_CHUNK):
                    conn.send(body[i:i + UPLOAD_CHUNK])
                    time.sleep(chunk_pause)
            else:
                conn.send(body)
        if on_sent:
            on_sent()
        r = conn.getresponse()
        data = r.read()
        length = r.getheader("Content-Length")
        if length is not None and int(length) != len(data):
            raise http.client.IncompleteRead(data, int(length) - len(data))
        return Response(r.status, {k.lower(): v for k, v in r.getheaders()}, data)
    finally:
        conn.close()


def post_json(base, path, doc, headers=None):
    h = {"Content-Type": "application/json"}
    h.update(headers or {})
    return request(base, "POST", path, json.dumps(doc).encode(), h)


# --- the server -------------------------------------------------------------


class Server:
    def __init__(self, bin_path, data_dir, out_dir, trace_dir):
        self.bin = bin_path
        self.data = data_dir
        self.out = out_dir
        self.trace = trace_dir
        self.proc = None
        self.base = None
        self.starts = 0

    def start(self, ms_per_frame):
        self.starts += 1
        with open(os.path.join(self.out, "server.log"), "ab") as f:
            f.write(f"\n===== start {self.starts} (slow:{ms_per_frame}) =====\n".encode())
        stdout_path = os.path.join(self.out, f"server-{self.starts}.stdout")
        env = dict(os.environ)
        env.update({
            "TREEMORPH_TEST_RUNNER": f"slow:{ms_per_frame},trace={self.trace}",
            "RUST_LOG": env.get("RUST_LOG", "info"),
            "NO_COLOR": "1",
        })
        stdout = open(stdout_path, "wb")
        stderr = open(os.path.join(self.out, "server.log"), "ab")
        self.proc = subprocess.Popen(
            [self.bin, "serve", "--listen", "127.0.0.1:0", "--data-dir", self.data,
             "--workers", "2", "--lease-secs", "2", "--poll-ms", "50",
             "--shutdown-grace", "5"],
            stdout=stdout, stderr=stderr, stdin=subprocess.DEVNULL, env=env)
        stdout.close()
        stderr.close()
        with open(os.path.join(self.out, "server.pid"), "w") as f:
            f.write(str(self.proc.pid))
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            with open(stdout_path, "rb") as f:
                line = f.readline().decode(errors="replace")
            if line.startswith("listening on ") and line.endswith("\n"):
                self.base = line[len("listening on "):].strip()
                return self.base
            if self.proc.poll() is not None:
                raise SystemExit(f"the server exited at start {self.starts} with {self.proc.returncode}; see server.log")
            time.sleep(0.005)
        raise SystemExit(f"the server printed no address within 30 s (start {self.starts})")

    def kill9(self):
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait()

    def terminate(self, within=30):
        self.proc.send_signal(signal.SIGTERM)
        try:
            return self.proc.wait(timeout=within)
        except subprocess.TimeoutExpired:
            self.kill9()
            return None

    def stop_quietly(self):
        if self.proc is not None and self.proc.poll() is None:
            self.kill9()


# --- what the clients were told ----------------------------------------------


class Ledger:
    """Everything the server acknowledged (thread-safe)."""

    def __init__(self):
        self.lock = threading.Lock()
        self.trees = {}  # id -> how it was made ("generated", "upload:json", "upload:glb")
        self.jobs = {}  # idempotency key -> {"body": ..., "id": None | id, "tries": n}
        self.cancels = {}  # job id -> "cancelled" | "requested" | "unacknowledged"
        self.uploads_started = 0
        self.uploads_acked = 0
        self.generated_acked = 0
        self.upload_states = {}  # uploader -> "idle" | "sending" | "processing"
        self.deletes = {}  # job id -> "deleted" (204) | "unacknowledged"
        self.rendering = False  # a frame.glb?t= request in flight
        self.renders_ok = 0
        self.kept = set()  # ids of the jobs the renderer can count on: never deleted

    def add_job(self, key, source, target):
        """Records the morph job to post under idempotency key `key`."""
        with self.lock:
            self.jobs[key] = {"body": {"kind": "morph", "source": source, "target": target, "frames": FRAMES},
                              "id": None, "tries": 0}

    def deleting(self):
        with self.lock:
            return set(self.deletes)

    def tree_ids(self):
        with self.lock:
            return list(self.trees)

    def acked_job_ids(self):
        with self.lock:
            return [j["id"] for j in self.jobs.values() if j["id"]]

    def pending_keys(self):
        with self.lock:
            return [k for k, j in self.jobs.items() if not j["id"]]


def uploader(name, base, ledger, files, stop):
    rng = random.Random()
    while not stop.is_set():
        kind, body, media = rng.choice(files)
        with ledger.lock:
            ledger.uploads_started += 1
            ledger.upload_states[name] = "sending"

        def sent():
            with ledger.lock:
                ledger.upload_states[name] = "processing"
        try:
            r = request(base, "POST", f"/v1/trees?name=crash-{kind}", body,
                        {"Content-Type": media}, on_sent=sent, chunk_pause=UPLOAD_CHUNK_PAUSE_S)
        except (OSError, http.client.HTTPException):
            with ledger.lock:
                ledger.upload_states[name] = "idle"
            return  # the server is gone
        with ledger.lock:
            ledger.upload_states[name] = "idle"
            if r.status == 201:
                ledger.trees[r.json()["id"]] = f"upload:{kind}"
                ledger.uploads_acked += 1
        check(r.status == 201, f"an upload of {kind} answered {r.status}: {r.body[:300]!r}")
        stop.wait(rng.uniform(0, 0.3))


def parse_rfc3339_ms(text):
    """`2026-11-22T06:03:06.952Z` -> seconds since the epoch."""
    return datetime.datetime.strptime(text, "%Y-%m-%dT%H:%M:%S.%fZ").replace(
        tzinfo=datetime.timezone.utc).timestamp()


def post_job(base, ledger, key):
    with ledger.lock:
        job = ledger.jobs[key]
        job["tries"] += 1
        body = job["body"]
    sent_at = time.time()
    r = post_json(base, "/v1/jobs", body, {"Idempotency-Key": key})
    check(r.status == 202, f"POST /v1/jobs ({key}) answered {r.status}: {r.body[:300]!r}")
    if r.status == 202:
        doc = r.json()
        with ledger.lock:
            if job["id"] is not None:
                check(job["id"] == doc["id"],
                      f"the retried job {key} got a new id {doc['id']} (was {job['id']})")
            job["id"] = doc["id"]
            # A retry answered with a job created before it was sent: the
            # lost answer's job, found again by its idempotency key.
            if job["tries"] > 1 and parse_rfc3339_ms(doc["created_at"]) < sent_at - 0.002:
                job["deduplicated"] = True


def driver(life, base, ledger, stop, rng, kill_at):
    """Generates trees, posts jobs (retrying unacknowledged ones with their
    idempotency key) and sometimes cancels one; then posts one more job
    timed to race the kill (so some acknowledgements are lost and retried),
    and polls the job list until the server dies."""
    try:
        for i in range(2):
            seed = life * 10 + i
            r = post_json(base, "/v1/trees/generate",
                          {"preset": rng.choice(["maple", "conifer", "shrub"]), "seed": seed, "size": 60})
            check(r.status == 201, f"POST /v1/trees/generate answered {r.status}: {r.body[:300]!r}")
            if r.status == 201:
                with ledger.lock:
                    ledger.trees[r.json()["id"]] = "generated"
                    ledger.generated_acked += 1
        for key in ledger.pending_keys():
            post_job(base, ledger, key)
        for n in range(JOBS_PER_LIFE):
            trees = ledger.tree_ids()
            a, b = rng.sample(trees, 2)
            key = f"crash-{life}-{n}"
            ledger.add_job(key, a, b)
            post_job(base, ledger, key)
            stop.wait(rng.uniform(0, 0.2))
        if rng.random() < 0.5:
            gone = ledger.deleting()
            ids = [j for j in ledger.acked_job_ids() if j not in gone]
            victim = rng.choice(ids)
            with ledger.lock:
                ledger.cancels.setdefault(victim, "unacknowledged")
            # POST …/cancel: DELETE would delete a job that has ended.
            r = request(base, "POST", f"/v1/jobs/{victim}/cancel")
            if r.status == 200:
                doc = r.json()
                with ledger.lock:
                    if doc["status"] == "cancelled":
                        ledger.cancels[victim] = "cancelled"
                    elif ledger.cancels[victim] != "cancelled":
                        ledger.cancels[victim] = "requested"
            else:
                check(r.status == 409, f"POST /v1/jobs/{victim}/cancel answered {r.status}: {r.body[:300]!r}")
        racer = f"crash-{life}-race"
        trees = ledger.tree_ids()
        a, b = rng.sample(trees, 2)
        ledger.add_job(racer, a, b)
        race_at = kill_at - rng.uniform(0, 0.008)
        while not stop.is_set() and time.monotonic() < race_at - 0.25:
            r = request(base, "GET", "/v1/jobs?limit=100")
            check(r.status == 200, f"GET /v1/jobs answered {r.status}")
            stop.wait(0.2)
        if not stop.is_set():
            time.sleep(max(0.0, race_at - time.monotonic()))
        post_job(base, ledger, racer)
        while not stop.is_set():
            r = request(base, "GET", "/v1/jobs?limit=100")
            check(r.status == 200, f"GET /v1/jobs answered {r.status}")
            stop.wait(0.2)
    except (OSError, http.client.HTTPException):
        return  # the server is gone


def instant_glb(t):
    """What the test runner renders at instant `t` (src/jobs/testing.rs)."""
    return b"glTF" + struct.pack("<f", t) + b"instant"


def renderer(base, ledger, stop, rng):
    """Asks for frames at instants of succeeded jobs, one after another
    (each takes a frame's time to render), until the server dies: most
    kills land while one renders. Instants are multiples of 1/1024, exact
    in binary, so the expected bytes do not depend on decimal rounding."""
    try:
        while not stop.is_set():
            r = request(base, "GET", "/v1/jobs?status=succeeded&limit=100")
            gone = ledger.deleting()
            ids = [j["id"] for j in r.json()["items"] if j["id"] not in gone] if r.status == 200 else []
            if not ids:
                stop.wait(0.2)
                continue
            jid, t = rng.choice(ids), rng.randrange(1025) / 1024
            with ledger.lock:
                ledger.rendering = True
            r = request(base, "GET", f"/v1/jobs/{jid}/frame.glb?t={t}")
            with ledger.lock:
                ledger.rendering = False
            if r.status == 404 and jid in ledger.deleting():
                continue
            if check(r.status == 200 and r.body == instant_glb(t),
                     f"GET /v1/jobs/{jid}/frame.glb?t={t} answered {r.status}: {r.body[:60]!r}"):
                with ledger.lock:
                    ledger.renders_ok += 1
    except (OSError, http.client.HTTPException):
        with ledger.lock:
            ledger.rendering = False


def start_render_jobs(base, ledger):
    """Runs RENDER_JOBS jobs to success on the first server, which is not
    killed, and keeps them from the deleter: the renderer then has
    instants to render from the first kill on. Left to the jobs of the
    killed lives, a slow machine once had none succeed for most lives,
    and only 3 of 20 kills hit a render."""
    a, b = ledger.tree_ids()[:2]
    for i in range(RENDER_JOBS):
        key = f"crash-0-render-{i}"
        ledger.add_job(key, a, b)
        post_job(base, ledger, key)
        jid = ledger.jobs[key]["id"]
        if jid is None:
            raise SystemExit(f"the render job {key} was not acknowledged")
        ledger.kept.add(jid)
    deadline = time.monotonic() + FINISH_DEADLINE_S
    while time.monotonic() < deadline:
        statuses = [request(base, "GET", f"/v1/jobs/{jid}").json()["status"] for jid in ledger.kept]
        if all(s == "succeeded" for s in statuses):
            return
        if any(s in TERMINAL and s != "succeeded" for s in statuses):
            raise SystemExit(f"a render job ended without succeeding: {statuses}")
        time.sleep(0.1)
    raise SystemExit(f"the render jobs did not succeed within {FINISH_DEADLINE_S} s")


def deleter(base, ledger, stop, rng, kill_at):
    """Deletes one ended job, sent within 30 ms before the kill, so some
    deletes are cut before their row goes, some between their row and
    their blobs, and some answered to a client that never hears it."""
    try:
        stop.wait(max(0.0, kill_at - 0.3 - time.monotonic()))
        r = request(base, "GET", "/v1/jobs?limit=100")
        spared = ledger.deleting() | ledger.kept
        ended = [j["id"] for j in r.json()["items"]
                 if j["status"] in TERMINAL and j["id"] not in spared] if r.status == 200 else []
        if not ended or stop.is_set():
            return
        jid = rng.choice(ended)
        time.sleep(max(0.0, kill_at - rng.uniform(0, 0.03) - time.monotonic()))
        with ledger.lock:
            ledger.deletes[jid] = "unacknowledged"
        r = request(base, "DELETE", f"/v1/jobs/{jid}")
        if r.status == 204:
            with ledger.lock:
                ledger.deletes[jid] = "deleted"
        else:
            check(False, f"DELETE of ended job {jid} answered {r.status}: {r.body[:200]!r}")
    except (OSError, http.client.HTTPException):
        return  # the server is gone; the delete stays unacknowledged


def check_deleted(base, ledger, jobs_by_id):
    """A delete the server acknowledged holds after every crash: the job
    is gone from the list and answers 404, outputs included. A delete cut
    by a kill either happened or not; a job still listed is verified
    like any other. Returns how many deleted jobs are gone."""
    gone = 0
    for jid, state in ledger.deletes.items():
        if jid in jobs_by_id:
            check(state == "unacknowledged", f"job {jid}: its delete was acknowledged, yet it is listed")
            continue
        gone += 1
        for suffix in ["", "/metrics.json", "/frame.glb?t=0.5", "/frames/0.glb"]:
            r = request(base, "GET", f"/v1/jobs/{jid}{suffix}")
            check(r.status == 404, f"deleted job {jid}: GET /v1/jobs/{jid}{suffix} answered {r.status}")
    return gone


# --- checks -------------------------------------------------------------------


def list_all(base, path):
    items, cursor = [], None
    while True:
        q = f"{path}?limit=100" + (f"&cursor={cursor}" if cursor else "")
        r = request(base, "GET", q)
        if not check(r.status == 200, f"GET {q} answered {r.status}: {r.body[:200]!r}"):
            return items
        doc = r.json()
        items.extend(doc["items"])
        cursor = doc.get("next_cursor")
        if not cursor:
            return items


def check_glb(data, what):
    if not check(len(data) >= 20 and data[:4] == b"glTF", f"{what}: not a GLB"):
        return
    version, length = struct.unpack_from("<II", data, 4)
    check(version == 2 and length == len(data),
          f"{what}: GLB header says version {version}, {length} bytes; got {len(data)}")
    off = 12
    chunks = 0
    while off + 8 <= len(data):
        clen, ctype = struct.unpack_from("<II", data, off)
        if not check(off + 8 + clen <= len(data), f"{what}: GLB chunk runs past the end"):
            return
        if chunks == 0:
            check(ctype == 0x4E4F534A, f"{what}: first GLB chunk is not JSON")
            try:
                json.loads(data[off + 8:off + 8 + clen])
            except ValueError as e:
                check(False, f"{what}: GLB JSON chunk does not parse: {e}")
        off += 8 + clen
        chunks += 1
    check(off == len(data) and chunks >= 1, f"{what}: GLB chunks do not fill the file")


def check_stream(data, frames, what):
    """Walks the delta stream record by record (api/README.md): preamble,
    CRC of every record, one header, `frames` frames, one end record that
    counts them, nothing after it."""
    if not check(data[:4] == b"TMDS" and len(data) >= 8, f"{what}: no TMDS preamble"):
        return
    off, kinds, end_count = 8, [], None
    while off < len(data):
        if not check(off + 12 <= len(data), f"{what}: record header cut short at byte {off}"):
            return
        kind, codec, _, stored, raw = struct.unpack_from("<BBHII", data, off)
        end = off + 12 + stored
        if not check(end + 4 <= len(data), f"{what}: record at byte {off} cut short"):
            return
        covered = data[off:end] if kinds else data[:8] + data[off:end]
        (crc,) = struct.unpack_from("<I", data, end)
        if not check(zlib.crc32(covered) == crc, f"{what}: CRC mismatch in record {len(kinds)}"):
            return
        if kind == 0x45 and codec == 0 and stored >= 4:
            (end_count,) = struct.unpack_from("<I", data, off + 12)
        kinds.append(kind)
        off = end + 4
    want = [0x48] + [0x46] * frames + [0x45]
    check(kinds == want, f"{what}: records {bytes(kinds)!r}, want H, {frames} x F, E")
    check(end_count == frames, f"{what}: the end record counts {end_count} frames, want {frames}")


class Verifier:
    def __init__(self, base, data_dir, ledger, trace):
        self.base = base
        self.blobs = os.path.join(data_dir, "blobs")
        self.ledger = ledger
        self.trace = trace
        self.downloads = 0
        self.bytes = 0
        self.stats = {}

    def get(self, path, what):
        r = request(self.base, "GET", path, timeout=60)
        self.downloads += 1
        self.bytes += len(r.body)
        check(r.status == 200, f"{what}: GET {path} answered {r.status}: {r.body[:200]!r}")
        return r

    def same_as_disk(self, body, key, what):
        """What the server served is exactly the committed blob `key`."""
        path = os.path.join(self.blobs, key)
        try:
            with open(path, "rb") as f:
                disk = f.read()
        except OSError as e:
            check(False, f"{what}: served, but the blob {key} is not on disk: {e}")
            return
        check(disk == body, f"{what}: served {len(body)} bytes that differ from the blob {key} ({len(disk)} bytes)")

    def tree(self, info):
        tid = info["id"]
        r = self.get(f"/v1/trees/{tid}", f"tree {tid}")
        if r.status != 200:
            return
        stats = r.json()["stats"]
        how = self.ledger.trees.get(tid, "unacknowledged")
        if how.startswith("upload:"):
            # Every upload of the same file gives the same statistics.
            first = self.stats.setdefault(how, stats)
            check(first == stats, f"tree {tid} ({how}): stats {stats} differ from another upload of the file {first}")
        doc = self.get(f"/v1/trees/{tid}/tree.json", f"tree {tid}")
        if doc.status == 200:
            self.same_as_disk(doc.body, f"trees/{tid}/tree.json", f"tree {tid} tree.json")
            try:
                d = json.loads(doc.body)
                check(len(d["nodes"]) == stats["branches"] + 1 and len(d["leaves"]) == stats["leaves"],
                      f"tree {tid}: tree.json has {len(d['nodes'])} nodes, {len(d['leaves'])} leaves; stats say {stats}")
            except (ValueError, KeyError, TypeError) as e:
                check(False, f"tree {tid}: tree.json does not parse: {e}")
        glb = self.get(f"/v1/trees/{tid}/model.glb", f"tree {tid}")
        if glb.status == 200:
            self.same_as_disk(glb.body, f"trees/{tid}/model.glb", f"tree {tid} model.glb")
            check_glb(glb.body, f"tree {tid} model.glb")
        an = self.get(f"/v1/trees/{tid}/analysis", f"tree {tid}")
        if an.status == 200:
            self.same_as_disk(an.body, f"trees/{tid}/analysis.json", f"tree {tid} analysis")
            try:
                json.loads(an.body)
            except ValueError as e:
                check(False, f"tree {tid}: the analysis does not parse: {e}")

    def job(self, info, last_token):
        jid, status = info["id"], info["status"]
        if status == "succeeded":
            self.succeeded(info)
            return
        # A failed or cancelled job keeps serving the frames its last
        # attempt published (frames_ready), and nothing else.
        ready = info["frames_ready"]
        if ready and not check(last_token is not None, f"job {jid} ({status}): {ready} frames ready but no attempt in the trace"):
            return
        for n in range(ready):
            r = self.get(f"/v1/jobs/{jid}/frames/{n}.glb", f"job {jid} ({status})")
            if r.status == 200:
                want = b"glTF" + struct.pack("<I", n) + last_token.encode()
                check(r.body == want, f"job {jid} ({status}) frame {n}: {r.body[:60]!r}, want {want!r}")
                self.same_as_disk(r.body, f"jobs/{jid}/{last_token}/frames/{n:06}.glb", f"job {jid} frame {n}")
        if ready < info["frames"]:
            r = request(self.base, "GET", f"/v1/jobs/{jid}/frames/{ready}.glb")
            check(r.status == 404, f"job {jid} ({status}) serves frame {ready} beyond frames_ready: {r.status}")
        for name in ["animation.glb", "metrics.json"]:
            r = request(self.base, "GET", f"/v1/jobs/{jid}/{name}")
            check(r.status == 404, f"job {jid} ({status}) serves {name}: {r.status}")

    def succeeded(self, info):
        jid, frames = info["id"], info["frames"]
        check(info["frames_ready"] == frames, f"job {jid}: frames_ready {info['frames_ready']} of {frames}")
        m = self.get(f"/v1/jobs/{jid}/metrics.json", f"job {jid}")
        if m.status != 200:
            return
        try:
            metrics = json.loads(m.body)
            token = metrics["attempt"]
        except (ValueError, KeyError) as e:
            check(False, f"job {jid}: metrics.json has no attempt token: {e}")
            return
        prefix = f"jobs/{jid}/{token}"
        self.same_as_disk(m.body, f"{prefix}/files/metrics.json", f"job {jid} metrics.json")
        check(metrics.get("frames") == frames, f"job {jid}: metrics say {metrics.get('frames')} frames")
        ends = self.trace.get((jid, token), {})
        check("start" in ends and ends.get("end") == "ok",
              f"job {jid}: the served attempt {token} has trace {ends} (want a start and an ok end)")
        stamp = token.encode()
        for n in range(frames):
            r = self.get(f"/v1/jobs/{jid}/frames/{n}.glb", f"job {jid}")
            if r.status == 200:
                want = b"glTF" + struct.pack("<I", n) + stamp
                check(r.body == want, f"job {jid} frame {n}: {r.body[:60]!r}, want {want!r} (a partial or superseded output?)")
                self.same_as_disk(r.body, f"{prefix}/frames/{n:06}.glb", f"job {jid} frame {n}")
        a = self.get(f"/v1/jobs/{jid}/animation.glb", f"job {jid}")
        if a.status == 200:
            want = b"glTF" + b"\xff\xff\xff\xff" + stamp
            check(a.body == want, f"job {jid} animation.glb: {a.body[:60]!r}, want {want!r}")
            self.same_as_disk(a.body, f"{prefix}/files/animation.glb", f"job {jid} animation.glb")
        s = self.get(f"/v1/jobs/{jid}/stream", f"job {jid}")
        if s.status == 200:
            check_stream(s.body, frames, f"job {jid} stream")
            self.same_as_disk(s.body, f"{prefix}/files/stream.tmd", f"job {jid} stream")


DELETES = 10


def delete_ended_jobs(base, data_dir, jobs):
    """Renders an instant of a succeeded job, then deletes DELETES ended
    jobs: each answers 204, then 404, and leaves no file under the data
    directory's blobs. Returns the ids deleted."""
    ended = [j for j in jobs if j["status"] in ("succeeded", "failed", "cancelled")]
    done = [j for j in ended if j["status"] == "succeeded"]
    if check(done, "no job succeeded"):
        jid = done[0]["id"]
        r = request(base, "GET", f"/v1/jobs/{jid}/frame.glb?t=0.375")
        want = instant_glb(0.375)
        check(r.status == 200 and r.body == want,
              f"GET /v1/jobs/{jid}/frame.glb?t=0.375 answered {r.status}: {r.body[:60]!r}, want {want!r}")
    deleted = []
    for j in ended[:DELETES]:
        jid = j["id"]
        r = request(base, "DELETE", f"/v1/jobs/{jid}")
        check(r.status == 204, f"DELETE of ended job {jid} ({j['status']}) answered {r.status}: {r.body[:200]!r}")
        r = request(base, "GET", f"/v1/jobs/{jid}")
        check(r.status == 404, f"deleted job {jid} answered {r.status}")
        left = []
        for root, _, files in os.walk(os.path.join(data_dir, "blobs", "jobs", jid)):
            left.extend(os.path.join(root, f) for f in files)
        check(not left, f"deleted job {jid} left {len(left)} files: {left[:3]}")
        deleted.append(jid)
    log(f"rendered an instant; deleted {len(deleted)} ended jobs")
    return deleted


def last_attempts(trace):
    """job -> token of its latest attempt (the one its row publishes)."""
    last = {}
    for (job, token), rec in trace.items():
        if "start" in rec and (job not in last or rec["start"] > last[job][0]):
            last[job] = (rec["start"], token)
    return {job: token for job, (_, token) in last.items()}


def read_trace(trace_dir):
    """(job, token) -> {"start": at_ms, "end": outcome}; a line cut short by
    kill -9 is skipped."""
    out = {}
    for name in os.listdir(trace_dir):
        if not name.endswith(".jsonl"):
            continue
        with open(os.path.join(trace_dir, name), errors="replace") as f:
            for line in f:
                try:
                    e = json.loads(line)
                except ValueError:
                    continue
                rec = out.setdefault((e["job"], e["token"]), {})
                if e["ev"] == "start":
                    rec["start"] = e["at_ms"]
                else:
                    rec["end"] = e.get("outcome")
    return out


def stray_files(data_dir, tree_ids, jobs_by_id, published):
    """Files a crash left behind that no row names: spooled uploads in tmp/,
    blob-store staging files (`name#N`), blobs of trees without a row, and
    job attempt directories other than the published one."""
    strays = {"tmp": [], "staging": [], "orphan tree dirs": [], "other attempt dirs": []}
    tmp = os.path.join(data_dir, "tmp")
    for name in sorted(os.listdir(tmp)) if os.path.isdir(tmp) else []:
        strays["tmp"].append(os.path.join("tmp", name))
    blobs = os.path.join(data_dir, "blobs")
    for root, dirs, files in os.walk(blobs):
        for name in files:
            tail = name.rsplit("#", 1)
            if len(tail) == 2 and tail[1].isdigit():
                strays["staging"].append(os.path.relpath(os.path.join(root, name), data_dir))
    trees = os.path.join(blobs, "trees")
    for tid in sorted(os.listdir(trees)) if os.path.isdir(trees) else []:
        if tid not in tree_ids:
            strays["orphan tree dirs"].append(f"blobs/trees/{tid}")
    jobs = os.path.join(blobs, "jobs")
    for jid in sorted(os.listdir(jobs)) if os.path.isdir(jobs) else []:
        for token in sorted(os.listdir(os.path.join(jobs, jid))):
            if published.get(jid) != token:
                d = os.path.join(jobs, jid, token)
                inside = [os.path.relpath(os.path.join(r, f), d) for r, _, fs in os.walk(d) for f in fs]
                strays["other attempt dirs"].append(
                    f"blobs/jobs/{jid}/{token} ({jobs_by_id.get(jid, {}).get('status')}; "
                    f"{len(inside)} files: {', '.join(sorted(inside)[:3])})")
    return strays


def open_ro(db_path):
    """Read-only: the crashed database's WAL stays as the next server
    start finds it (a read-write close would checkpoint it away)."""
    return sqlite3.connect(f"file:{db_path}?mode=ro", uri=True, timeout=30)


def integrity(db_path, what):
    try:
        con = open_ro(db_path)
        try:
            rows = con.execute("PRAGMA integrity_check").fetchall()
        finally:
            con.close()
    except sqlite3.Error as e:
        check(False, f"{what}: cannot open {db_path}: {e}")
        return "error"
    result = "; ".join(r[0] for r in rows)
    check(result == "ok", f"{what}: PRAGMA integrity_check says {result}")
    return result


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", required=True)
    ap.add_argument("--work", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=None)
    a = ap.parse_args()
    seed = a.seed if a.seed is not None else random.randrange(1 << 30)
    rng = random.Random(seed)
    log(f"random seed {seed} (repeat with CRASH_SAFETY_SEED={seed})")
    started = time.monotonic()

    data_dir = os.path.join(a.work, "data")
    trace_dir = os.path.join(a.work, "trace")
    os.makedirs(data_dir, exist_ok=True)
    os.makedirs(trace_dir, exist_ok=True)
    db_path = os.path.join(data_dir, "treemorph.db")

    # Upload bodies of a few MB: a treemorph tree JSON and a GLB.
    files = []
    for kind, preset, size, ext, media in [
        ("json", "willow", "6000", "json", "application/vnd.treemorph.tree+json"),
        ("glb", "maple", "3000", "glb", "model/gltf-binary"),
    ]:
        path = os.path.join(a.work, f"upload.{ext}")
        subprocess.run([a.bin, "generate", "--preset", preset, "--seed", "7", "--size", size, "-o", path],
                       check=True, capture_output=True)
        with open(path, "rb") as f:
            files.append((kind, f.read(), media))
    log("upload bodies: " + ", ".join(f"{k} {len(b) / 1e6:.1f} MB" for k, b, _ in files))

    server = Server(a.bin, data_dir, a.out, trace_dir)
    ledger = Ledger()
    kills = []
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    try:
        # Two trees to start from, on a first server that is not killed.
        base = server.start(MS_PER_FRAME)
        for i in range(2):
            r = post_json(base, "/v1/trees/generate", {"preset": "maple", "seed": 900 + i, "size": 60})
            if r.status != 201:
                raise SystemExit(f"POST /v1/trees/generate answered {r.status}: {r.body[:300]!r}")
            ledger.trees[r.json()["id"]] = "generated"
            ledger.generated_acked += 1
        start_render_jobs(base, ledger)
        server.terminate()

        for life in range(1, KILLS + 1):
            base = server.start(MS_PER_FRAME)
            stop = threading.Event()
            threads = [threading.Thread(target=uploader, args=(f"u{i}", base, ledger, files, stop), daemon=True)
                       for i in range(UPLOADERS)]
            delay = rng.uniform(*KILL_AFTER_S)
            kill_at = time.monotonic() + delay
            threads.append(threading.Thread(target=driver, args=(life, base, ledger, stop, random.Random(rng.random()),
                                                                 kill_at), daemon=True))
            threads.append(threading.Thread(target=renderer, args=(base, ledger, stop, random.Random(rng.random())),
                                            daemon=True))
            threads.append(threading.Thread(target=deleter, args=(base, ledger, stop, random.Random(rng.random()),
                                                                  kill_at), daemon=True))
            for t in threads:
                t.start()
            time.sleep(max(0.0, kill_at - time.monotonic()))
            with ledger.lock:
                states = dict(ledger.upload_states)
                rendering = ledger.rendering
            server.kill9()
            stop.set()
            for t in threads:
                t.join(timeout=30)
                check(not t.is_alive(), "a client thread hung after the kill")
            sending = sum(1 for s in states.values() if s == "sending")
            processing = sum(1 for s in states.values() if s == "processing")
            kills.append({"after": delay, "sending": sending, "processing": processing, "rendering": rendering})
            log(f"kill {life:2}: after {delay:.2f} s; uploads in flight: {sending} sending, "
                f"{processing} being processed; acknowledged so far: {len(ledger.acked_job_ids())} jobs, "
                f"{ledger.uploads_acked} uploads, {ledger.generated_acked} generated trees")

        crashed_integrity = integrity(db_path, "after the last kill")

        # The last start: no kill; everything must finish.
        base = server.start(FINAL_MS_PER_FRAME)
        for key in ledger.pending_keys():
            post_job(base, ledger, key)
        deadline = time.monotonic() + FINISH_DEADLINE_S
        while True:
            jobs = list_all(base, "/v1/jobs")
            open_jobs = [j for j in jobs if j["status"] not in TERMINAL]
            if not open_jobs or time.monotonic() > deadline:
                break
            time.sleep(0.5)
        check(not open_jobs, f"{len(open_jobs)} jobs not terminal {FINISH_DEADLINE_S} s after the last start: "
                             f"{[(j['id'], j['status']) for j in open_jobs[:5]]}")
        drained = time.monotonic()

        trace = read_trace(trace_dir)
        trees = list_all(base, "/v1/trees")
        tree_ids = {t["id"] for t in trees}
        jobs_by_id = {j["id"]: j for j in jobs}

        # Nothing acknowledged is lost, and nothing appeared twice.
        lost_trees = [t for t in ledger.trees if t not in tree_ids]
        check(not lost_trees, f"{len(lost_trees)} acknowledged trees are gone: {lost_trees[:5]}")
        acked_jobs = ledger.acked_job_ids()
        lost_jobs = [j for j in acked_jobs if j not in jobs_by_id and j not in ledger.deletes]
        check(not lost_jobs, f"{len(lost_jobs)} acknowledged jobs are gone: {lost_jobs[:5]}")
        check(len(ledger.pending_keys()) == 0, f"jobs never acknowledged: {ledger.pending_keys()[:5]}")
        deleted_gone = check_deleted(base, ledger, jobs_by_id)
        check(len(jobs_by_id) + deleted_gone == len(ledger.jobs),
              f"{len(jobs_by_id)} jobs listed and {deleted_gone} deleted for {len(ledger.jobs)} idempotency keys "
              f"(a duplicate or phantom job)")
        for tid in lost_trees:
            r = request(base, "GET", f"/v1/trees/{tid}")
            check(False, f"acknowledged tree {tid}: GET answered {r.status}")

        # Every job terminal, for a reason this test can explain.
        for j in jobs:
            cancel = ledger.cancels.get(j["id"])
            if j["status"] == "cancelled":
                check(cancel is not None, f"job {j['id']} is cancelled but nobody cancelled it")
            if cancel == "cancelled":
                check(j["status"] == "cancelled", f"job {j['id']}: its cancellation was acknowledged, yet it is {j['status']}")
            if cancel == "requested":
                check(j["status"] in ("cancelled", "succeeded"),
                      f"job {j['id']}: cancellation requested while running, yet it is {j['status']}")
            if j["status"] == "failed":
                err = j.get("error") or {}
                check(j["attempt"] >= MAX_ATTEMPTS and "stopped responding" in err.get("message", ""),
                      f"job {j['id']} failed for another reason than its worker dying {MAX_ATTEMPTS} times: "
                      f"attempt {j['attempt']}, {err}")

        # Everything listed is complete and exactly what was committed.
        v = Verifier(base, data_dir, ledger, trace)
        last = last_attempts(trace)
        for t in trees:
            v.tree(t)
        for j in jobs:
            v.job(j, last.get(j["id"]))

        # Files a crash left behind: listed, and none of them may be served.
        strays = stray_files(data_dir, tree_ids, jobs_by_id, last)
        for d in strays["orphan tree dirs"]:
            tid = d.rsplit("/", 1)[1]
            for suffix in ["", "/tree.json", "/model.glb", "/analysis"]:
                r = request(base, "GET", f"/v1/trees/{tid}{suffix}")
                check(r.status == 404, f"the orphan blobs of tree {tid} are served: GET /v1/trees/{tid}{suffix} -> {r.status}")
        # Superseded attempts: every served output carries the published
        # attempt's token (checked above); staging files have names no key
        # maps to, and every served blob was compared with its committed file.
        with open(os.path.join(a.out, "strays.json"), "w") as f:
            json.dump(strays, f, indent=1)

        # Renders on request and deletion, after the crashes: the frame at
        # an instant of a succeeded job, then ended jobs deleted with every
        # blob they own.
        for jid in delete_ended_jobs(base, data_dir, jobs):
            jobs_by_id.pop(jid)

        # A clean stop, then the database on disk.
        code = server.terminate()
        check(code == 0, f"the last server did not stop cleanly on SIGTERM (exit {code})")
        final_integrity = integrity(db_path, "after the last stop")
        con = open_ro(db_path)
        try:
            dangling = con.execute(
                "SELECT count(*) FROM jobs WHERE tree_a NOT IN (SELECT id FROM trees) "
                "OR (tree_b IS NOT NULL AND tree_b NOT IN (SELECT id FROM trees))").fetchone()[0]
            leased = con.execute("SELECT count(*) FROM jobs WHERE lease_token IS NOT NULL").fetchone()[0]
            db_jobs = con.execute("SELECT count(*) FROM jobs").fetchone()[0]
            db_trees = con.execute("SELECT count(*) FROM trees").fetchone()[0]
        finally:
            con.close()
        check(dangling == 0, f"{dangling} jobs name a tree that has no row")
        check(leased == 0, f"{leased} finished jobs still hold a lease")
        check(db_jobs == len(jobs_by_id) and db_trees == len(tree_ids),
              f"database rows ({db_jobs} jobs, {db_trees} trees) differ from the API's lists "
              f"({len(jobs_by_id)}, {len(tree_ids)})")

        with open(os.path.join(a.out, "server.log"), errors="replace") as f:
            log_lines = f.readlines()
        panics = [l.rstrip() for l in log_lines if "panicked" in l]
        errors = [l.rstrip() for l in log_lines if " ERROR " in l]
        check(not panics, f"the server panicked: {panics[:3]}")

        # Coverage: the kills did hit uploads and running jobs.
        during_upload = sum(1 for k in kills if k["sending"] or k["processing"])
        cut = sum(1 for rec in trace.values() if "start" in rec and "end" not in rec)
        check(during_upload >= MIN_KILLS_DURING_UPLOAD,
              f"only {during_upload} kills hit an upload in flight (want >= {MIN_KILLS_DURING_UPLOAD})")
        check(cut >= MIN_ATTEMPTS_CUT, f"only {cut} job attempts were cut by a kill (want >= {MIN_ATTEMPTS_CUT})")
        during_render = sum(1 for k in kills if k["rendering"])
        check(during_render >= MIN_KILLS_DURING_RENDER,
              f"only {during_render} kills hit a render in flight (want >= {MIN_KILLS_DURING_RENDER})")
        deletes_acked = sum(1 for d in ledger.deletes.values() if d == "deleted")
        check(deleted_gone >= MIN_DELETES_DONE,
              f"only {deleted_gone} deletes racing a kill took effect (want >= {MIN_DELETES_DONE})")

        statuses = {}
        for j in jobs:
            statuses[j["status"]] = statuses.get(j["status"], 0) + 1
        attempts = {}
        for j in jobs:
            attempts[j["attempt"]] = attempts.get(j["attempt"], 0) + 1
        cancels = {}
        for c in ledger.cancels.values():
            cancels[c] = cancels.get(c, 0) + 1
        rows = [
            ("kills (kill -9)", f"{len(kills)}, after {min(k['after'] for k in kills):.2f}-{max(k['after'] for k in kills):.2f} s of life"),
            ("kills during an upload", f"{during_upload} ({sum(k['sending'] for k in kills)} bodies being sent, "
                                       f"{sum(k['processing'] for k in kills)} being processed)"),
            ("job attempts cut by a kill", str(cut)),
            ("kills during a render", f"{during_render} ({ledger.renders_ok} instants rendered and checked)"),
            ("deletes racing a kill", f"{len(ledger.deletes)}: {deletes_acked} acknowledged, "
                                      f"{len(ledger.deletes) - deletes_acked} cut, of which {deleted_gone} jobs are gone"),
            ("jobs acknowledged", f"{len(acked_jobs)} ({sum(1 for j in ledger.jobs.values() if j['tries'] > 1)} after a retry with their "
                                  f"Idempotency-Key, {sum(1 for j in ledger.jobs.values() if j.get('deduplicated'))} of them "
                                  f"committed before the kill)"),
            ("uploads acknowledged", f"{ledger.uploads_acked} of {ledger.uploads_started} started"),
            ("generated trees acknowledged", str(ledger.generated_acked)),
            ("trees listed (unacknowledged)", f"{len(tree_ids)} ({len(tree_ids) - len(ledger.trees)})"),
            ("final job statuses", ", ".join(f"{k} {v}" for k, v in sorted(statuses.items()))),
            ("attempts per job", ", ".join(f"{k}: {v}" for k, v in sorted(attempts.items()))),
            ("cancellations sent", ", ".join(f"{k} {v}" for k, v in sorted(cancels.items())) or "none"),
            ("lost (trees / jobs)", f"{len(lost_trees)} / {len(lost_jobs)}"),
            ("integrity_check", f"{crashed_integrity} after the last kill, {final_integrity} after the last stop"),
            ("downloads verified", f"{v.downloads} ({v.bytes / 1e6:.0f} MB), each equal to its committed blob"),
            ("stray files (never served)", ", ".join(f"{k} {len(x)}" for k, x in strays.items())),
            ("server log", f"{len(panics)} panics, {len(errors)} ERROR lines"),
            ("all jobs terminal after", f"{drained - started:.0f} s"),
            ("wall time (helper)", f"{time.monotonic() - started:.0f} s"),
        ]
        width = max(len(k) for k, _ in rows)
        log("")
        log("crash-safety summary")
        for k, val in rows:
            log(f"  {k.ljust(width)}  {val}")
        if errors:
            log("first ERROR lines of the server log:")
            for l in errors[:5]:
                log(f"  {l}")
    finally:
        server.stop_quietly()

    if failures:
        log("")
        log(f"{len(failures)} assertion(s) failed:")
        for f in failures[:50]:
            log(f"  - {f}")
        sys.exit(1)
    log("crash-safety test passed")


if __name__ == "__main__":
    main()
