"""The live view: a web page showing the gateways' telemetry as it happens (docs/view.md).

- `state.ViewState`: sans-IO, the JSON tree's messages in, the frames the page draws out;
- `web`: the page's HTTP, sans-IO (a fixed list of files, the Host rule, one POST);
- `commands`: sans-IO, the commands offered, per-page tokens, each checked with the
  gateway's parser before it is published (`--allow-commands` only);
- `server.LiveView`: the edge, aiomqtt's subscription and the asyncio HTTP server
  streaming frames (Server-Sent Events); `static/`: the page and the vendored uPlot;
- `snapshot`: headless Chromium saving the page as a PNG (`make demo`; selenium, dev only).
"""
