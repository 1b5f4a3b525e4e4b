"""Robot servers only their owner can move: CURVE keys and allow-lists, ownership by token and key, every bad
serve flag and request field refused with a message, the owner first under a flood (issue #34)."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest
import zmq
from inprocess_server import thread_server

from unilab_jax.robots import inventory, keys, protocol, serve
from unilab_jax.robots.client import RobotClient, query
from unilab_jax.robots.interface import RobotClaimed, RobotDisconnected, RobotEstopped

HOLD = np.array([0.0, 0, 0, 0, 0, 0, -1.0], dtype=np.float32)
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "bench"))
import flood_clients  # noqa: E402  (bench/flood_clients.py: the flood's process)


@pytest.fixture
def keydir(tmp_path):
    """A server pair, two admitted clients (owner, other) and a stranger the server does not admit."""
    keys.new("server", str(tmp_path))
    for name in ("owner", "other"):
        keys.new(name, str(tmp_path / "allow"))
    keys.new("stranger", str(tmp_path / "elsewhere"))
    return tmp_path


def client_keys(keydir, name: str, folder: str = "allow") -> keys.ClientKeys:
    public, secret = keys.load_pair(str(keydir / folder / f"{name}.key_secret"))
    return keys.ClientKeys(public, secret, keys.load_public(str(keydir / "server.key")))


def raw_call(address: str, payload: bytes, keys_: keys.ClientKeys | None = None, timeout_s: float = 2.0):
    """One request on a fresh socket: the reply, or None if the server stays silent."""
    ctx = zmq.Context()
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    if keys_ is not None:
        sock.curve_serverkey, sock.curve_publickey, sock.curve_secretkey = keys_.server, keys_.public, keys_.secret
    try:
        sock.connect(address)
        sock.send(payload)
        return protocol.unpack(sock.recv()) if sock.poll(timeout_s * 1000) else None
    finally:
        sock.close(0)
        ctx.term()


def test_keys_cli_makes_lists_and_refuses_to_overwrite(tmp_path, capsys):
    folder = str(tmp_path / "k")
    assert keys.main(["new", "franka1", "--dir", folder]) == 0
    assert oct(os.stat(os.path.join(folder, "franka1.key_secret")).st_mode & 0o777) == "0o600"
    public = keys.load_public(os.path.join(folder, "franka1.key"))
    assert keys.main(["list", "--dir", folder]) == 0
    out = capsys.readouterr().out
    assert public.decode() in out and "public + secret" in out
    assert keys.main(["new", "franka1", "--dir", folder]) == 2
    assert "already exists" in capsys.readouterr().err
    with pytest.raises(keys.KeyFileError, match="holds no secret key"):
        keys.load_pair(os.path.join(folder, "franka1.key"))


def test_keyed_server_admits_only_allowed_keys_and_only_the_owner_moves_the_robot(keydir, client):
    owner_keys, other_keys = client_keys(keydir, "owner"), client_keys(keydir, "other")
    stranger_keys = client_keys(keydir, "stranger", "elsewhere")
    with thread_server(float("inf"), 0.0, key_file=str(keydir / "server.key_secret"),
                       allow_dir=str(keydir / "allow")) as server:
        owner = client(server.address, client_id="trainer", keys=owner_keys, heartbeat_s=0)
        owner.connect()
        owner.reset(seed=0)
        owner.step(HOLD)
        # No key, or a key the server does not admit: no answer at all, whatever the request.
        for payload in (protocol.request("claim", 1, "trainer", {"lease_s": 3600}),
                        protocol.request("step", 2, "trainer", {"action": HOLD}, owner._token),
                        protocol.request("release", 3, "trainer", None, owner._token),
                        protocol.request("health", 4, "x")):
            assert raw_call(server.address, payload, timeout_s=0.2) is None
            assert raw_call(server.address, payload, stranger_keys, timeout_s=0.2) is None
        with pytest.raises(RobotDisconnected, match="refused this client's key"):
            client(server.address, keys=stranger_keys, timeout_s=0.3, heartbeat_s=0).connect()
        # An admitted client that knows the owner's name (health shows it) and even its token cannot act as it.
        _, health = query(server.address, keys=other_keys)
        assert health.owner == "trainer" and health.limit_hits["denied"] >= 4
        for op, args, token in (("claim", {"lease_s": 3600}, ""), ("claim", {"lease_s": 3600}, owner._token),
                                ("step", {"action": HOLD}, owner._token), ("release", None, owner._token),
                                ("clear_estop", None, ""), ("heartbeat", None, owner._token), ("reset", None, "")):
            reply = raw_call(server.address, protocol.request(op, 5, "trainer", args, token), other_keys)
            assert reply["error"]["type"] == "RobotClaimed", (op, reply)
        # estop is open to every admitted client; clearing it is the owner's
        assert raw_call(server.address, protocol.request("estop", 6, "other"), other_keys)["ok"]
        with pytest.raises(RobotEstopped):
            owner.step(HOLD)
        owner.clear_estop()
        assert owner.step(HOLD).obs["proprio"].shape == (13,)
        owner.close()
        intruder = client(server.address, client_id="trainer", keys=other_keys, heartbeat_s=0)
        intruder.connect()  # released: now anyone admitted may claim it
        intruder.reset(seed=1)


def test_unkeyed_loopback_server_ties_ownership_to_the_claims_token(client):
    with thread_server(float("inf"), 0.0) as server:
        owner = client(server.address, client_id="first", heartbeat_s=0)
        owner.connect()
        owner.reset(seed=0)
        # the name is public, the token is not: a client reusing the name is refused everything
        name_only = client(server.address, client_id="first", heartbeat_s=0)
        with pytest.raises(RobotClaimed, match="claimed by client 'first'"):
            name_only.connect()
        for op in ("step", "release", "clear_estop", "heartbeat"):
            reply = raw_call(server.address, protocol.request(op, 1, "first", {"action": HOLD}, "guess"))
            assert reply["error"]["type"] == "RobotClaimed"
        assert owner.heartbeat().owner == "first"
        # the owner may change its lease by claiming again with its token
        reply = raw_call(server.address, protocol.request("claim", 2, "first", {"lease_s": 0.2}, owner._token))
        assert reply["ok"] and reply["result"]["token"] == owner._token
        time.sleep(0.5)  # that lease ran out: the robot is stopped and free
        name_only.connect()
        assert name_only.health().state == "estopped"


@pytest.mark.parametrize("args,message", [
    (["--speed=0"], "speed"), (["--speed=-1"], "speed"), (["--speed=nan"], "speed"),
    (["--host=999.1.1.1"], "host must be an IP address"), (["--port=99999"], "port must be in"),
    (["--lease_s=-1"], "lease_s"), (["--lease_s=nan"], "lease_s"), (["--reset_s=-1"], "reset_seconds"),
    (["--latency_ms=inf"], "latency_s"), (["--image_size=8"], "image_size"), (["--seed=-3"], "seed"),
    (["--max_message_bytes=0"], "max_message_bytes"), (["--fault=drop:2"], "drop_reply_prob"),
    (["--host=0.0.0.0"], "reachable from the network"), (["--host=192.168.1.20"], "reachable from the network"),
    (["--key=nowhere.key_secret"], "both key_file"), (["--key=nowhere.key_secret", "--allow=."], "nowhere"),
    (["--workspace=1,2"], "--workspace needs 6"), (["--workspace=1,0,0,0,1,1"], "box_low"),
    (["--workspace=0,0,0,0.005,1,1"], "margin"),
    (["--cone_deg=0"], "cone_deg"), (["--max_force=-1"], "max_force"), (["--max_joint_speed=nan"], "max_joint"),
])
def test_bad_serve_flags_exit_2_with_a_message(args, message, capsys):
    assert serve.main(["--robot=franka", "--task=pick_place", "--cameras=none", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1, err


def test_network_bind_without_keys_exits_2_without_a_traceback():
    proc = subprocess.run([sys.executable, "-m", "unilab_jax.robots.serve", "--robot=franka", "--task=pick_place",
                           "--cameras=none", "--host=0.0.0.0", "--port=5555"], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and "--key" in proc.stderr, proc.stderr


def test_malformed_request_fields_are_bad_requests():
    with thread_server(float("inf"), 0.0) as server:
        claim = raw_call(server.address, protocol.request("claim", 1, "c"))
        token = claim["result"]["token"]
        cases = [("claim", {"lease_s": [1]}, ""), ("claim", {"lease_s": "5"}, ""), ("claim", {"lease_s": True}, ""),
                 ("claim", {"lease_s": float("nan")}, ""), ("claim", {"lease_s": 1e9}, ""),
                 ("reset", {"seed": "a"}, token), ("reset", {"seed": -1}, token), ("reset", {"seed": 1.5}, token),
                 ("step", {"action": "abcdefg"}, token), ("step", {"action": [{}] * 7}, token),
                 ("step", {"action": {"a": 1}}, token)]
        for op, args, tok in cases:
            reply = raw_call(server.address, protocol.request(op, 2, "c", args, tok))
            assert reply["error"]["type"] == "BadRequest", (op, args, reply)
        for msg in ({"op": "ping", "id": True, "client": "c"}, {"op": "ping", "id": 1, "client": "c", "token": 5}):
            assert raw_call(server.address, protocol.pack(msg))["error"]["type"] == "BadRequest"


def test_inventory_toml_names_server_keys_and_the_client_key(keydir, tmp_path):
    toml = tmp_path / "robots.toml"
    toml.write_text('[client]\nkey = "allow/owner.key_secret"\n[[robot]]\nsim = "franka_emika_panda"\n'
                    '[[robot]]\naddress = "tcp://10.0.0.5:5555"\nserver_key = "server.key"\n')
    sim, remote = inventory.parse(str(toml))
    assert not sim.server_key and remote.server_key == keys.load_public(str(keydir / "server.key")).decode()
    (ring,) = inventory.client_keys((remote.server_key,), remote.client_key)
    assert ring == client_keys(keydir, "owner")
    toml.write_text('[[robot]]\naddress = "tcp://10.0.0.5:5555"\nserver_key = "server.key"\n')
    with pytest.raises(inventory.InventoryError, match=r"needs \[client\] key"):
        inventory.parse(str(toml))
    toml.write_text('[client]\nkey = "allow/owner.key"\n[[robot]]\naddress = "tcp://10.0.0.5:5555"\n'
                    'server_key = "server.key"\n')
    with pytest.raises(inventory.InventoryError, match="holds no secret key"):
        inventory.parse(str(toml))


def test_the_owners_request_is_answered_before_requests_queued_ahead_of_it():
    """The server's order, without timing: while the robot is inside a paced step (1 s at speed 0.1), another
    client queues health requests and then the owner pipelines its next step. The owner's step is answered first,
    so every health reply already counts it; a server answering in arrival order counts one step fewer in all."""
    with thread_server(0.1, 0.0) as server:
        ctx = zmq.Context()
        owner, other = ctx.socket(zmq.DEALER), ctx.socket(zmq.DEALER)
        try:
            for sock in (owner, other):
                sock.setsockopt(zmq.LINGER, 0)
                sock.connect(server.address)

            def reply(sock: zmq.Socket) -> dict:
                assert sock.poll(10_000), "no reply within 10 s"
                return protocol.unpack(sock.recv())

            owner.send(protocol.request("claim", 1, "owner", {"lease_s": 60}))
            token = reply(owner)["result"]["token"]
            owner.send(protocol.request("reset", 2, "owner", {"seed": 0}, token))
            assert reply(owner)["ok"]
            owner.send(protocol.request("step", 3, "owner", {"action": HOLD}, token))
            time.sleep(0.3)  # the server is inside step 3's 1 s period
            for i in range(20):
                other.send(protocol.request("health", 100 + i, "other"))
            owner.send(protocol.request("step", 4, "owner", {"action": HOLD}, token))
            assert [reply(owner)["id"] for _ in range(2)] == [3, 4]
            health = [reply(other) for _ in range(20)]
        finally:
            owner.close(0)
            other.close(0)
            ctx.term()
    assert [h["id"] for h in health] == list(range(100, 120))
    assert {h["result"]["steps"] for h in health} == {2}


def test_owner_keeps_its_robot_through_a_flood_of_health_requests_and_strangers(serve, keydir):
    """200 admitted sockets asking health four at a time as fast as they are answered, plus a connection with an
    unknown key every 5 ms (bench/flood_clients.py): every owner step is answered, the strangers are refused and the
    flood is cut to the rate limit. The owner's latency under this flood is a benchmark
    (``bench/robots.py --parts flood``), not a test: on a shared 2-core machine it measures the neighbours."""
    server = serve("--robot=franka", "--task=pick_place", "--port=0", "--speed=inf", "--reset_s=0",
                   "--cameras=none", f"--key={keydir / 'server.key_secret'}", f"--allow={keydir / 'allow'}",
                   env={"OMP_NUM_THREADS": "1"})
    server_key = keys.load_public(str(keydir / "server.key")).decode()
    with RobotClient(server.address, keys=client_keys(keydir, "owner"), timeout_s=5.0, lease_s=60,
                     heartbeat_s=0) as robot:
        robot.reset(seed=0)
        flood = flood_clients.launch(server.address, 2, 200, server_key, str(keydir / "allow" / "other.key_secret"))
        try:
            steps = 0
            while flood.poll() is None:
                step = robot.step(HOLD if steps % 2 else -HOLD)  # RobotDisconnected after 5 s without its reply
                steps += 1
                if step.terminated or step.truncated:
                    robot.reset()
        finally:
            out = flood.communicate(timeout=30)[0]
        health = robot.health()
    flood_counts = flood_clients.counts(out)
    assert health.owner == robot.client_id and health.state != "estopped" and steps > 100
    assert health.limit_hits["denied"] > 0 and health.limit_hits["rate_limited"] > 0 and flood_counts["replies"] > 0
