"""Serve the API from one or several processes.

uvicorn's own ``--workers`` shares one listening socket between its processes, and the
kernel hands a burst of new connections to whichever process wakes first: under load one
process ends up with every keep-alive client while the others idle. Here each process
gets its own listening socket in one ``SO_REUSEPORT`` group, so the kernel spreads
connections across them. The parent opens every socket before any process starts (no
process takes all early clients while the others are still importing), restarts a
process that dies on the same socket, and stops them all on SIGINT/SIGTERM.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import socket
import time
from multiprocessing.process import BaseProcess

import uvicorn

from services.lib.process import die_with_parent

APP = "supervisor.app:create_app"
RESTART_PAUSE_S = 1.0
STOP_TIMEOUT_S = 30.0
BACKLOG = 2048

log = logging.getLogger("vista.serve")


def listening_socket(host: str, port: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
    try:
        sock.bind((host, port))
        sock.listen(BACKLOG)
    except OSError:
        sock.close()
        raise
    return sock


def _serve_one(sock: socket.socket, access_log: bool, parent_pid: int) -> None:
    """One API process: one uvicorn server on its own socket, ended with its parent."""
    die_with_parent(parent_pid)
    config = uvicorn.Config(
        APP, factory=True, log_level="info", access_log=access_log, backlog=BACKLOG
    )
    uvicorn.Server(config).run(sockets=[sock])


def serve(host: str, port: int, *, processes: int, access_log: bool) -> None:
    """Serve until interrupted; ``processes`` > 1 runs that many balanced API processes."""
    if processes == 1:
        uvicorn.run(
            APP, factory=True, host=host, port=port, log_level="info", access_log=access_log
        )
        return
    sockets = []
    try:
        for _ in range(processes):
            sockets.append(listening_socket(host, port))
    except OSError:
        for sock in sockets:
            sock.close()
        raise
    context = multiprocessing.get_context("spawn")
    stopping = False

    def start(sock: socket.socket) -> BaseProcess:
        process = context.Process(
            target=_serve_one,
            args=(sock, access_log, os.getpid()),
            name="vista-api",
            daemon=False,
        )
        process.start()
        return process

    def stop(signum: int, _frame: object) -> None:
        nonlocal stopping
        stopping = True

    previous = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    children = [start(sock) for sock in sockets]
    try:
        while not stopping:
            time.sleep(0.2)
            for index, child in enumerate(children):
                if not child.is_alive() and not stopping:
                    log.warning(
                        "API process %s exited with code %s; starting another",
                        child.pid,
                        child.exitcode,
                    )
                    time.sleep(RESTART_PAUSE_S)
                    children[index] = start(sockets[index])
    finally:
        for child in children:
            if child.is_alive() and child.pid is not None:
                child.terminate()  # SIGTERM: uvicorn finishes open requests, then exits
        deadline = time.monotonic() + STOP_TIMEOUT_S
        for child in children:
            child.join(max(0.0, deadline - time.monotonic()))
            if child.is_alive():
                child.kill()
                child.join()
        for sock in sockets:
            sock.close()
        for signum, handler in previous.items():
            signal.signal(signum, handler)
