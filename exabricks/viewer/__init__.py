"""`exabricks view` and `eb.view`: a progressive viewer in the browser or a notebook
(docs/view.md).

- `session`: the dataset on the device and the progressive frames of the scene
  a page edits (a scene file's object: what "Save scene" writes);
- `page`: one page's scene, its frames in stages and its saves, on whatever
  channel the page comes (a websocket, a widget's comm);
- `server`: the web server (aiohttp): the page, its assets, one websocket per
  page, a token and an Origin check as a Jupyter server has them;
- `guard`: the server against clients without the token: their connections
  bounded and timed out, each kind of refusal logged once, in one line;
- `notebook`: `eb.view`, the page in a notebook's output cell (an anywidget
  widget over the kernel's comm);
- `static/`: the page (HTML, JavaScript, CSS), shipped in the package: no CDN.
"""
