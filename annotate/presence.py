"""Other ``zcut annotate`` servers on the same label store: this server's row and heartbeat.

Each server registers itself in the store's ``servers`` table (:meth:`annotate.store.LabelStore.register_server`)
and beats every :data:`HEARTBEAT_S` seconds; :meth:`Presence.others` are the other live servers,
asked afresh each time (a server started a moment ago is seen at once). The command warns about
them when it starts and the page shows them: edits from both are kept, but one annotator on two
servers meets conflicts.
"""

from __future__ import annotations

import threading
import time

from annotate.store import LabelStore, ServerRecord, StoreError

HEARTBEAT_S = 5.0


class Presence:
    """This server's row in the store's ``servers`` table and its heartbeat thread (until :meth:`stop`).

    Parameters
    ----------
    store : LabelStore
    log_sha256 : str
        The served log's content hash.
    port : int or None
        The port on 127.0.0.1 (None when unknown).
    """

    def __init__(self, store: LabelStore, *, log_sha256: str, port: int | None) -> None:
        self.store = store
        self.me: ServerRecord = store.register_server(log_sha256=log_sha256, port=port)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, name="zcut-annotate-heartbeat", daemon=True)
        self._thread.start()

    def others(self) -> list[ServerRecord]:
        """The other live servers of the store."""
        return [s for s in self.store.live_servers() if s.id != self.me.id]

    def _beat(self) -> None:
        while not self._stop.wait(HEARTBEAT_S):
            try:
                self.store.heartbeat_server(self.me.id)
            except StoreError:  # the store went away (shutting down): nothing to tell
                return

    def stop(self) -> None:
        """Stop beating and leave the table."""
        self._stop.set()
        self._thread.join(timeout=10)
        try:
            self.store.unregister_server(self.me.id)
        except StoreError:
            pass


def describe_server(s: ServerRecord) -> str:
    """One line about another server: process, port and start time."""
    started = time.strftime("%H:%M:%S", time.localtime(s.started_ns / 1e9))
    port = f"port {s.port}" if s.port else "unknown port"
    return f"zcut annotate (pid {s.pid} on {s.host}, {port}, since {started})"
