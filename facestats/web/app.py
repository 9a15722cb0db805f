"""The Flask application of ``facestats serve``: the §7 applet over a read-only store.

Routes (GET only; every other method is 405):

* ``/`` — the population page (filters, tables, plots; static JS/CSS shipped in the package);
* ``/api/query`` — the ``facestats.query/1`` document of ``facestats query --format json``
  (the same call, :meth:`facestats.io.store.Store.query` → ``to_dict``); ``/api/query.csv`` its CSV;
* ``/api/pca``, ``/api/scatter`` — Fig. 15 ellipses and Fig. 14 points of the matching subjects;
* ``/subject/<id>`` — a subject page; ``/api/subject/<id>``, ``/subject/<id>/map/<name>.png`` (its scale in
  the PNG's text chunks, as the ``edit`` images'), ``/subject/<id>/preview.png``, ``/subject/<id>/exr.zip``
  (the EXR texture set) and ``/subject/<id>/gltf.zip`` (the glTF 2.0 asset of ``export-subject --format
  gltf``).  Subjects that hold region samples (``facestats import-merl``) have no maps: their page links no
  preview or downloads, and those answer 400 saying so.

Safety: the store is opened read-only; filter names are whitelisted and values
bounded in length; subject ids pass :func:`facestats.io.ids.check_subject_id`
before any use (no path is ever built from a request); query strings are at
most :data:`MAX_QUERY_STRING` bytes and bodies :data:`MAX_BODY` bytes.  Work
that grows with a subject's maps (map and preview images, the EXR set) runs
for at most :data:`MAX_HEAVY` requests at once; others wait their turn, up to
:data:`HEAVY_WAIT` seconds, then get 503 and are asked to retry; images are
enlarged only up to :data:`facestats.web.data.MAX_IMAGE_SIDE` pixels a side;
the EXR set and the glTF asset are zipped into a temporary file (stored, not recompressed) and
streamed from there, never held in memory; a subject is read inside its turn,
so at most :data:`MAX_HEAVY` are loaded for such work at once.  The last few
subjects read are kept by id *and* generation: a subject another process
rewrote or removed is read again or answered 404, never served from memory.
JSON answers hold no NaN or infinities (``null`` instead).  Errors
are JSON (API) or a short page: the text is the Python API's message as the CLI prints it
(``facestats: error: ...``; the CLI names its options where the message starts with a parameter, e.g.
``--skin-type must ...`` for ``skin type must ...``), with 400 (bad value), 404 (unknown subject or
page), 409 (store fails its checks), 424 (missing optional dependency), 503
(image or export requests waited too long for their turn); an
unexpected exception is logged on the server and answered with a generic 500,
never a traceback.
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
import threading
import zipfile
from collections import OrderedDict

from facestats.core.conventions import CONDITIONS, REGIONS, ROMAN
from facestats.core.outputs import json_ready
from facestats.errors import DependencyError, FacestatsError, StoreError, ValidationError

__all__ = [
    "create_app",
    "DOWNLOADS",
    "FILTERS",
    "MAX_QUERY_STRING",
    "MAX_BODY",
    "MAX_HEAVY",
    "HEAVY_WAIT",
    "error_text",
]

FILTERS = ("skin_type", "gender", "age", "condition", "region", "edits")
#: Values of the ``edits`` filter (``facestats query --edits``): include the subjects written by edits, or not.
EDITS_VALUES = {"": False, "0": False, "false": False, "no": False, "1": True, "true": True, "yes": True,
                "include": True}  # fmt: skip
MAX_QUERY_STRING = 1024
MAX_BODY = 1024
MAX_VALUE = 32
#: Requests that build images or the EXR set, at once (per server); more wait up to HEAVY_WAIT seconds, then 503.
MAX_HEAVY = 2
HEAVY_WAIT = 30.0
_LOG = logging.getLogger("facestats.web")


def error_text(exc) -> str:
    """The message of a :class:`FacestatsError` as the CLI prints it (``facestats: error: ...``), in the API's words.

    Parameters
    ----------
    exc : Exception
        The error; its ``str()`` is the message.

    Returns
    -------
    str
    """
    return f"facestats: error: {exc}"


def _status(exc) -> int:
    # local import: keeps numpy out of this module's import
    from facestats.io.subject_export import UnknownSubjectError

    if isinstance(exc, UnknownSubjectError):
        return 404
    if isinstance(exc, DependencyError):
        return 424
    if isinstance(exc, StoreError):
        return 409
    return 400


class _SubjectCache:
    """The last few subjects read (a page asks for several maps of one subject).

    Keyed by id and generation: a subject another process rewrote since (a new
    generation in the index) is read again, and one it removed is no longer served.
    """

    def __init__(self, store, lock, size=8):
        self._store, self._lock, self._size = store, lock, size
        self._items = OrderedDict()

    def get(self, sid):
        # local import: keeps numpy out of this module's import
        from facestats.io.subject_export import store_subject

        with self._lock:
            entry = self._store.index_entries().get(sid)  # the index is re-read when its file changed
            key = (sid, None if entry is None else entry["generation"])
            if entry is not None and key in self._items:
                self._items.move_to_end(key)
                return self._items[key]
            # Lazy: a page reads its attributes and, per image, the maps it shows (strided to the image's size,
            # facestats.web.data.image_view); an eager read held every map of up to 8 subjects (2.5 GB after two
            # 2048² subjects; the speed red team).  Chunks are CRC-checked as they are read.
            ds = store_subject(self._store, sid, lazy=True)
            self._items[key] = ds
            while len(self._items) > self._size:
                self._items.popitem(last=False)
            return ds

    def read(self, sid, work):
        """``work(subject)``, once more on the new generation if the subject was replaced while ``work`` read it.

        A lazy subject reads its chunks when ``work`` asks for them; a writer that replaced the subject meanwhile
        has removed those files, which reads as a damaged chunk (``StoreError``).  A subject still at the same
        generation is really damaged: its error stands.
        """
        ds = self.get(sid)
        try:
            return work(ds)
        except StoreError:
            again = self.get(sid)
            if again is ds:
                raise
            return work(again)


def _filters(args) -> dict:
    """The whitelisted, length-bounded filters of a request (empty values mean "any", but an empty or absent
    ``condition`` means the query's default, ``normal``, as ``facestats query``; ``condition=any`` pools them)."""

    unknown = sorted(set(args) - set(FILTERS))
    if unknown:
        raise ValidationError(f"unknown filter(s) {unknown}; expected some of {list(FILTERS)}")
    out = {}
    for key in FILTERS:
        if len(args.getlist(key)) > 1:
            raise ValidationError(f"filter {key} must be given once, got {args.getlist(key)[:4]!r}")
        value = args.get(key, "").strip()
        if len(value) > MAX_VALUE:
            raise ValidationError(f"{key} must be at most {MAX_VALUE} characters, got {len(value)}")
        out[key] = value or None
    if out["condition"] is None:  # not given: the query's default (normal), as the CLI's; "any" pools them all
        del out["condition"]
    edits = (out.pop("edits") or "").lower()
    if edits not in EDITS_VALUES:
        raise ValidationError(f"filter edits must be one of {sorted(set(EDITS_VALUES) - {''})}, got {edits!r}")
    out["edits"] = EDITS_VALUES[edits]
    return out


def _host_name(host: str) -> str:
    """The name part of a ``Host`` header (``[::1]:8000`` → ``::1``, ``localhost:80`` → ``localhost``)."""
    host = host.strip().lower()
    if host.startswith("["):
        return host[1 : host.find("]")] if "]" in host else host
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


def create_app(store=None, *, preload=True, allowed_hosts=None):
    """The Flask app over ``store`` (a path, a read-only :class:`~facestats.io.store.Store` or None: the default).

    Parameters
    ----------
    store : str, os.PathLike, Store or None
    preload : bool
        Start reading the region samples for Fig. 15 in the background now.
    allowed_hosts : iterable of str, optional
        Host names a request's ``Host`` header may carry (others get 400): what
        :func:`facestats.web.serve` passes on loopback, against DNS rebinding.

    Returns
    -------
    flask.Flask
        ``app.config["FACESTATS_STORE"]`` holds the open store.
    """
    try:
        from flask import Flask
    except ImportError as exc:
        raise DependencyError(
            f"Flask is not installed (needed by facestats serve): pip install 'facestats[web]' ({exc})"
        )
    # local import: keeps numpy out of this module's import
    from facestats.io.store import Store, open_store
    from facestats.web.data import RegionSamples

    st = store if isinstance(store, Store) else open_store(store, mode="r")
    if not st.read_only:
        raise StoreError(f"the web app serves read-only stores; open {st.label} with mode='r'")
    here = os.path.dirname(os.path.abspath(__file__))
    app = Flask(__name__, static_folder=os.path.join(here, "static"), template_folder=os.path.join(here, "templates"))
    app.config.update(MAX_CONTENT_LENGTH=MAX_BODY, FACESTATS_STORE=st)
    app.json.sort_keys = False  # keep the documented key order of facestats.query/1
    lock = threading.RLock()
    ctx = {
        "store": st,
        "lock": lock,
        "samples": RegionSamples(st, start=preload),
        "subjects": _SubjectCache(st, lock),
        "heavy": threading.BoundedSemaphore(MAX_HEAVY),
        "heavy_wait": HEAVY_WAIT,
    }
    app.config["FACESTATS"] = ctx
    _register_guards(app, None if allowed_hosts is None else frozenset(h.lower() for h in allowed_hosts))
    _register_routes(app, ctx)
    return app


def _check_request(request, allowed_hosts):
    """Abort a request to another host name, with another method than GET/HEAD, or beyond the size limits."""
    from flask import abort

    if allowed_hosts is not None and _host_name(request.host) not in allowed_hosts:
        shown = request.headers.get("Host", "")[:64]  # as sent: werkzeug's request.host is '' when it cannot parse it
        abort(400, f"unexpected Host header {shown!r}: this server answers {sorted(allowed_hosts)}")
    if request.method not in ("GET", "HEAD"):
        abort(405, valid_methods=["GET", "HEAD"])
    if len(request.query_string) > MAX_QUERY_STRING:
        abort(414)
    if (request.content_length or 0) > MAX_BODY:
        abort(413)


def _register_guards(app, allowed_hosts):
    from flask import jsonify, render_template, request
    from werkzeug.exceptions import HTTPException

    @app.before_request
    def _limits():
        _check_request(request, allowed_hosts)

    def _reply(status, message):
        if request.path.startswith("/api/"):
            return jsonify({"error": message, "status": status}), status
        return render_template("error.html", status=status, message=message), status

    @app.errorhandler(FacestatsError)
    def _facestats_error(exc):
        return _reply(_status(exc), error_text(exc))

    @app.errorhandler(HTTPException)
    def _http_error(exc):
        body, status = _reply(exc.code, f"facestats: error: {exc.name}: {exc.description}")
        allow = dict(exc.get_headers()).get("Allow")  # 405 names the methods allowed (RFC 9110 §15.5.6)
        return body, status, ({"Allow": allow} if allow else {})

    @app.errorhandler(Exception)
    def _unexpected(exc):
        _LOG.exception("unexpected error serving %s", request.path)
        return _reply(500, "facestats: error: internal error (the server log has the details)")


def _register_routes(app, ctx):
    from flask import Response, jsonify, render_template, request

    st, lock = ctx["store"], ctx["lock"]

    def query():
        with lock:
            return st.query(**_filters(request.args))

    @app.get("/")
    def index():
        return render_template(
            "index.html", store=st.label, n=len(st), conditions=CONDITIONS, regions=REGIONS, roman=ROMAN
        )

    @app.get("/api/query")
    def api_query():
        return jsonify(query().to_dict())

    @app.get("/api/query.csv")
    def api_query_csv():
        return Response(
            query().to_csv(), mimetype="text/csv",
            headers={"Content-Disposition": "attachment; filename=facestats-query.csv"},
        )  # fmt: skip

    @app.get("/api/pca")
    def api_pca():
        # local import: keeps numpy out of this module's import
        from facestats.web.data import pca_document

        ids = query().subject_ids
        with lock:  # pooled from the store's index (or from the samples read in the background)
            doc = pca_document(ctx["samples"], ids)
        return jsonify(json_ready(doc)), (202 if doc["status"] == "pending" else 200)  # overflow: null, not NaN

    @app.get("/api/scatter")
    def api_scatter():
        # local import: keeps numpy out of this module's import
        from facestats.web.data import scatter_document

        ids = query().subject_ids
        with lock:
            return jsonify(scatter_document(st, ids))

    _register_subject_routes(app, ctx)


def _register_subject_routes(app, ctx):
    from flask import Response, jsonify, render_template
    from werkzeug.exceptions import ServiceUnavailable

    # local import: keeps numpy out of this module's import
    from facestats.web.data import map_png, preview_png, subject_document

    cache, heavy = ctx["subjects"], ctx["heavy"]

    def bounded(work):
        """``work()`` once fewer than :data:`MAX_HEAVY` heavy requests run (503 after :data:`HEAVY_WAIT` s)."""
        if not heavy.acquire(timeout=ctx["heavy_wait"]):
            raise ServiceUnavailable(f"{MAX_HEAVY} image or export requests are running; try again in a moment")
        try:
            return work()
        finally:
            heavy.release()

    @app.get("/api/subject/<sid>")
    def api_subject(sid):
        return jsonify(json_ready(cache.read(sid, subject_document)))

    @app.get("/subject/<sid>")
    def subject_page(sid):
        doc = cache.read(sid, subject_document)
        return render_template("subject.html", doc=doc, sid=doc["subject"]["subject_id"])

    @app.get("/subject/<sid>/map/<name>.png")
    def subject_map(sid, name):
        return Response(bounded(lambda: cache.read(sid, lambda ds: map_png(ds, name))), mimetype="image/png")

    @app.get("/subject/<sid>/preview.png")
    def subject_preview(sid):
        return Response(bounded(lambda: cache.read(sid, preview_png)), mimetype="image/png")

    @app.get("/subject/<sid>/exr.zip")
    def subject_exr(sid):
        return _download(cache, bounded, sid, "exr")

    @app.get("/subject/<sid>/gltf.zip")
    def subject_gltf(sid):
        return _download(cache, bounded, sid, "gltf")


#: The subject downloads, ``/subject/<id>/KIND.zip``: kind → what it is (in messages).
DOWNLOADS = {"exr": "an EXR texture set", "gltf": "a glTF asset"}


def _download(cache, bounded, sid, kind):
    """GET or HEAD of one of :data:`DOWNLOADS`: the subject is read inside the slot ``bounded`` gives too, so at
    most :data:`MAX_HEAVY` are loaded for exports at once."""
    from flask import request, send_file

    if request.method == "HEAD":
        return _download_head(cache.get(sid), kind)
    archive, name = bounded(lambda: cache.read(sid, lambda ds: (_zip_export(ds, kind), ds.attrs["subject_id"])))
    size = os.fstat(archive.fileno()).st_size
    response = send_file(archive, mimetype="application/zip", as_attachment=True, download_name=f"{name}-{kind}.zip")
    response.content_length = size  # a file object gives werkzeug no length: say it, for download progress
    return response


def _download_head(ds, kind):
    """The answer to ``HEAD .../KIND.zip``: the checks and headers of a GET without building the export.

    Building it costs seconds of CPU and a temporary copy on disk, too much for a download manager's probe,
    so the response carries no ``Content-Length`` (RFC 9110 §9.3.2 allows a HEAD to omit it).  Checked: a map
    subject (not region samples) and, for the EXR set, OpenEXR installed.
    """
    # local imports: keep numpy (and flask, until an app is made) out of this module's import
    from flask import Response

    from facestats.io.exr_set import check_map_subject
    from facestats.io.images import require_openexr

    check_map_subject(ds, DOWNLOADS[kind])
    if kind == "exr":
        require_openexr()
    name = ds.attrs["subject_id"]
    return Response(
        iter(()),  # an iterable, not a sequence: werkzeug then sets no Content-Length of 0
        mimetype="application/zip",
        headers={"Content-Disposition": f"attachment; filename={name}-{kind}.zip"},
    )


def _zip_export(ds, kind):
    """The subject's export of ``kind`` (:data:`DOWNLOADS`: the EXR texture set of
    :func:`facestats.io.exr_set.write_exr_set`, or the glTF asset of :func:`facestats.io.gltf.write_gltf`, each with
    the face mesh the subject records) zipped into a temporary file.

    Returns an open binary file at its start, deleted when closed (the response closes it); the EXR and PNG files
    are compressed already, so the zip stores them as they are.
    """
    # local imports: keep numpy out of this module's import
    from facestats.io.exr_set import check_map_subject, write_exr_set
    from facestats.io.gltf import write_gltf

    check_map_subject(ds, DOWNLOADS[kind])  # before any temporary file
    tmp = tempfile.mkdtemp(prefix="facestats-web-")
    archive = tempfile.TemporaryFile(prefix="facestats-web-", suffix=".zip")
    try:
        if kind == "exr":
            write_exr_set(ds, tmp)
        else:
            write_gltf(ds, tmp)  # face.gltf, as facestats export-subject --format gltf writes it
        with zipfile.ZipFile(archive, "w", zipfile.ZIP_STORED) as zf:
            for name in sorted(os.listdir(tmp)):
                zf.write(os.path.join(tmp, name), arcname=name)
        archive.seek(0)
        return archive
    except BaseException:
        archive.close()
        raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
