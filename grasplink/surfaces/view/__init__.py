"""The live view: a web page showing the gateways' telemetry as it happens, or a recording
(docs/view.md).

- `state.ViewState`: sans-IO, the JSON tree's messages in, the frames the page draws out;
- `web`: the page's HTTP, sans-IO (a fixed list of files, the Host rule, one POST);
- `commands`: sans-IO, the commands offered, per-page tokens, each checked with the
  gateway's parser before it is published (`--allow-commands` only);
- `server.LiveView`: the edge, aiomqtt's subscription and the asyncio HTTP server
  streaming frames (Server-Sent Events); `static/`: the page and the vendored uPlot;
- `recording`: a `grasplink run` folder checked and replayed once (a listening `Gateway`,
  telemetry's `JsonTree`) into the messages the page is fed, with the truth beside them;
  `playback`: sans-IO, each page's playback clock and `ViewState` on the run's clock;
  `recording_server`: the edge for `grasplink view DIR` (the same page, GET only);
- `snapshot`: headless Chromium saving the page as a PNG (`make demo`; selenium, dev only).
"""
