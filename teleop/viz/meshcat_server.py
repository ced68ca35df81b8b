"""The meshcat server a view runs, and the pages it serves: complete when they load.

Meshcat 0.3.2's server (``ZMQWebSocketBridge``) serves a page that starts empty and gets the
scene over a websocket after it has loaded, and its ``static_html()`` page applies each command
through an asynchronous ``fetch()``: either way the labels, the legend and the arm's meshes
arrive after the page's load event, and a screenshot taken then misses them. :class:`Bridge`
changes four things:

* its web server binds the address it is given (meshcat's listens on every interface);
* ``/static/`` (the page's URL) is a page that holds the whole scene as it stands, applied
  synchronously by the page's own script (:func:`page`), so it is complete when it loads; it then
  connects to the websocket for the live frames, asking only for the commands that came after
  the scene it holds (``?since=N``; the whole scene again if those are no longer kept);
* ``get_scene`` (``Visualizer.static_html()``) returns the same page without the websocket: a
  recording complete on load;
* it exits as soon as the process that started it is gone (run as a script:
  ``python meshcat_server.py PARENT_PID HOST``).

Importing this module imports meshcat's server (tornado, zmq); the view runs it as a script.
"""

from __future__ import annotations

import base64
import collections
import os
import sys
import threading
import time

from meshcat.servers import zmqserver
from meshcat.servers.tree import walk

#: how many forwarded commands the server keeps for pages that connect after it served them
#: (about 30 s of a live view's frames)
KEPT_COMMANDS = 50_000
#: the data URI every command is written as (the form meshcat's own static page uses)
DATA_URI = "data:application/octet-binary;base64,"


def scene_commands(tree) -> list[bytes]:
    """The commands that rebuild ``tree`` (meshcat's SceneTree), in the order meshcat's own
    ``get_scene`` and ``send_scene`` send them: each node's object, properties, transform and
    animation, parents first."""
    out: list[bytes] = []
    for node in walk(tree):
        if node.object is not None:
            out.append(node.object)
        out += list(node.properties)
        if node.transform is not None:
            out.append(node.transform)
        if node.animation is not None:
            out.append(node.animation)
    return out


def page(commands, script: str, since: int | None = None, title: str = "teleop") -> str:
    """An HTML page of the meshcat viewer that applies ``commands`` (msgpack bytes) one by one,
    synchronously, while it loads (so a screenshot taken at its load event holds them), then, when
    ``since`` is given, connects to its server's websocket for the commands after number
    ``since``. ``script``: the viewer's javascript, inline (``main.min.js``'s text) or the tag
    that loads it."""
    calls = "\n".join(f'teleop_command("{DATA_URI}{base64.b64encode(c).decode("ascii")}");' for c in commands)
    ws = '(location.protocol == "https:" ? "wss://" : "ws://") + location.host'
    connect = "" if since is None else f'viewer.connect({ws} + "/?since={since}");'

    return f"""<!DOCTYPE html>
<html>
<head><meta charset="utf-8"><title>{title}</title>
<style>body {{margin: 0;}} #meshcat-pane {{width: 100vw; height: 100vh; overflow: hidden;}}</style>
</head>
<body>
<div id="meshcat-pane"></div>
{script}
<script>
var viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
function teleop_command(uri) {{  // one meshcat command, base64 in a data URI, applied now
  var bytes = atob(uri.slice(uri.indexOf(",") + 1)), a = new Uint8Array(bytes.length);
  for (var i = 0; i < bytes.length; i++) a[i] = bytes.charCodeAt(i);
  viewer.handle_command_bytearray(a);
}}
{calls}
{connect}
</script>
</body>
</html>
"""


def _inline_script() -> str:
    with open(os.path.join(zmqserver.VIEWER_ROOT, "main.min.js"), encoding="utf-8") as f:
        return f"<script>\n{f.read()}\n</script>"


class _Page(zmqserver.tornado.web.RequestHandler):
    """The live page: the scene as it stands, then the websocket."""

    def initialize(self, bridge):
        self.bridge = bridge

    def get(self):
        self.set_header("Cache-Control", "no-store, no-cache, must-revalidate, max-age=0")
        self.set_header("Content-Type", "text/html; charset=utf-8")
        b = self.bridge
        self.write(page(scene_commands(b.tree), '<script src="main.min.js"></script>', since=b.sequence))


class _Socket(zmqserver.WebSocketHandler):
    """A page's websocket: the commands after the scene the page holds (``?since=N``), or the
    whole scene when the page holds none or those commands are no longer kept."""

    def open(self):
        b = self.bridge
        b.websocket_pool.add(self)
        missed = b.commands_since(self.get_argument("since", None))
        if missed is None:
            b.send_scene(self)
        else:
            for data in missed:
                self.write_message(data, binary=True)


class Bridge(zmqserver.ZMQWebSocketBridge):
    """Meshcat's server with the pages of the module docstring; its web server binds ``web_host``."""

    def __init__(self, web_host: str = "127.0.0.1", **kw):
        self.web_host = web_host
        self.sequence = 0  # commands forwarded so far
        self.kept: collections.deque = collections.deque(maxlen=KEPT_COMMANDS)  # (number, data)
        super().__init__(**kw)

    def make_app(self):
        app = zmqserver.tornado.web.Application([
            (r"/static/(?:index\.html)?", _Page, {"bridge": self}),
            (r"/static/(.*)", zmqserver.StaticFileHandlerNoCache, {"path": zmqserver.VIEWER_ROOT}),
            (r"/", _Socket, {"bridge": self}),
        ])
        listen = app.listen
        app.listen = lambda port, **kw: listen(port, address=self.web_host, **kw)
        return app

    def forward_to_websockets(self, frames):
        if frames[0].decode("utf-8") in zmqserver.MESHCAT_COMMANDS:
            self.sequence += 1
            self.kept.append((self.sequence, frames[2]))
        super().forward_to_websockets(frames)

    def commands_since(self, since) -> list[bytes] | None:
        """The data of the commands forwarded after number ``since``, or None when ``since`` is
        not a number this server gave or the oldest of them is no longer kept."""
        try:
            n = int(since)
        except (TypeError, ValueError):
            return None
        if not 0 <= n <= self.sequence or (n < self.sequence and (not self.kept or self.kept[0][0] > n + 1)):
            return None
        return [data for k, data in self.kept if k > n]

    def handle_zmq(self, frames):
        if frames[0].decode("utf-8") == "get_scene":  # a recording: the page, complete, no websocket
            self.zmq_socket.send(page(scene_commands(self.tree), _inline_script()).encode("utf-8"))
            return
        super().handle_zmq(frames)


def main(argv) -> None:
    """Run the server for process ``argv[1]`` (exit when it is gone), its web server on ``argv[2]``;
    print its urls (``zmq_url=...``, ``web_url=...``)."""
    parent, web_host = int(argv[1]), argv[2]

    def watch():
        while os.getppid() == parent:
            time.sleep(0.25)
        os._exit(0)

    threading.Thread(target=watch, daemon=True).start()
    bridge = Bridge(web_host=web_host, host="127.0.0.1")
    shown = "[" + web_host + "]" if ":" in web_host else web_host
    print("zmq_url=" + bridge.zmq_url, flush=True)
    print(f"web_url=http://{shown}:{bridge.fileserver_port}/static/", flush=True)
    bridge.run()


if __name__ == "__main__":
    main(sys.argv)
