"""`exabricks view`: a progressive viewer in the browser (docs/view.md).

- `session`: the dataset on the device and the progressive frames of the scene
  a page edits (a scene file's object: what "Save scene" writes);
- `server`: the web server (aiohttp): the page, its assets, one websocket per
  page, a token and an Origin check as a Jupyter server has them;
- `static/`: the page (HTML, JavaScript, CSS), shipped in the package: no CDN.
"""
