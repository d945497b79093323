//! The web view (`http-api.md`: "served at `/ui`"): the live computation graph and its control
//! panel, static files embedded in the binary (`server/ui/`). The page uses only the public HTTP
//! API and its Server-Sent Events; nothing here knows the model.

use axum::Router;
use axum::extract::Path;
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Redirect, Response};
use axum::routing::get;

use crate::app::AppState;
use crate::error::{ApiError, ErrorBody};

/// One embedded file: its path under `/ui/`, media type and bytes.
struct Asset {
    path: &'static str,
    media_type: &'static str,
    bytes: &'static [u8],
}

macro_rules! asset {
    ($path:literal, $media_type:literal) => {
        Asset {
            path: $path,
            media_type: $media_type,
            bytes: include_bytes!(concat!("../../ui/", $path)),
        }
    };
}

/// The page, its script and style, and the vendored libraries with their licences.
const ASSETS: &[Asset] = &[
    asset!("index.html", "text/html; charset=utf-8"),
    asset!("app.js", "text/javascript; charset=utf-8"),
    asset!("graph.js", "text/javascript; charset=utf-8"),
    asset!("style.css", "text/css; charset=utf-8"),
    asset!("vendor/cytoscape.min.js", "text/javascript; charset=utf-8"),
    asset!(
        "vendor/cytoscape-dagre.min.js",
        "text/javascript; charset=utf-8"
    ),
    asset!("vendor/LICENSE.cytoscape", "text/plain; charset=utf-8"),
    asset!(
        "vendor/LICENSE.cytoscape-dagre",
        "text/plain; charset=utf-8"
    ),
    asset!("vendor/LICENSE.dagre", "text/plain; charset=utf-8"),
    asset!("vendor/README.md", "text/markdown; charset=utf-8"),
];

/// The routes: `/` and `/ui` lead to `/ui/`, the page; `/ui/{file}` the embedded files.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/", get(root))
        .route("/ui", get(ui_bare))
        .route("/ui/", get(page))
        .route("/ui/{*file}", get(file))
}

/// The service's root leads to the web view.
#[utoipa::path(get, path = "/", tag = "web view",
    responses((status = 303, description = "`Location: /ui/`")))]
pub async fn root() -> Redirect {
    Redirect::to("/ui/")
}

/// `/ui` leads to `/ui/` (the page's files are relative to it).
#[utoipa::path(get, path = "/ui", tag = "web view",
    responses((status = 303, description = "`Location: /ui/`")))]
pub async fn ui_bare() -> Redirect {
    Redirect::to("/ui/")
}

/// The web view's page: the live computation graph and its control panel (`docs/ui.md`).
#[utoipa::path(get, path = "/ui/", tag = "web view",
    params(("If-None-Match" = Option<String>, Header, description = "an entity tag of the page seen before")),
    responses((status = 200, content_type = "text/html", body = String, description = "the page, with `ETag`, `Cache-Control: no-cache` and a `Content-Security-Policy`"),
              (status = 304, description = "the page is unchanged")))]
pub async fn page(headers: HeaderMap) -> Response {
    serve("index.html", &headers)
}

/// One of the page's files: its scripts, style and vendored libraries with their licences.
#[utoipa::path(get, path = "/ui/{file}", tag = "web view",
    params(("file" = String, Path, description = "the file's path under `/ui/`, e.g. `app.js` or `vendor/cytoscape.min.js`"),
           ("If-None-Match" = Option<String>, Header, description = "an entity tag of the file seen before")),
    responses((status = 200, description = "the file, with `ETag` and `Cache-Control: no-cache`",
                content((String = "text/javascript"), (String = "text/css"), (String = "text/plain"), (String = "text/markdown"))),
              (status = 304, description = "the file is unchanged"),
              (status = 404, body = ErrorBody)))]
pub async fn file(Path(file): Path<String>, headers: HeaderMap) -> Response {
    serve(&file, &headers)
}

/// An embedded file, with an entity tag of its content (the binary's files change only with the
/// binary, so a browser revalidates and gets 304 until the service is upgraded).
fn serve(path: &str, headers: &HeaderMap) -> Response {
    let Some((index, asset)) = ASSETS.iter().enumerate().find(|(_, a)| a.path == path) else {
        return ApiError::not_found(format!("no file /ui/{path} in the web view")).into_response();
    };
    let etag = &ETAGS[index];
    let fresh = headers
        .get(header::IF_NONE_MATCH)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.split(',').any(|t| t.trim() == etag.as_str()));
    let mut response = if fresh {
        StatusCode::NOT_MODIFIED.into_response()
    } else {
        (
            [(
                header::CONTENT_TYPE,
                HeaderValue::from_static(asset.media_type),
            )],
            asset.bytes,
        )
            .into_response()
    };
    let h = response.headers_mut();
    if let Ok(v) = HeaderValue::from_str(etag) {
        h.insert(header::ETAG, v);
    }
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    // Scripts and styles only from the service itself: no inline script, no other origin.
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(
            "default-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; \
             object-src 'none'; base-uri 'none'; frame-ancestors 'none'",
        ),
    );
    response
}

/// The entity tag of each asset (its content hash), computed once.
static ETAGS: std::sync::LazyLock<Vec<String>> = std::sync::LazyLock::new(|| {
    ASSETS
        .iter()
        .map(|a| format!("\"{:016x}\"", fnv1a(a.bytes)))
        .collect()
});

/// FNV-1a, 64 bits: a stable content hash for entity tags.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(*b)).wrapping_mul(0x0100_0000_01b3)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_asset_is_embedded_and_the_page_names_only_embedded_files() {
        let page = std::str::from_utf8(ASSETS[0].bytes).expect("utf-8");
        for a in ASSETS {
            assert!(!a.bytes.is_empty(), "{}", a.path);
        }
        // Every script and style the page loads is one of ours (no CDN).
        for attr in ["src=\"", "href=\""] {
            for part in page.split(attr).skip(1) {
                let target = part.split('"').next().unwrap_or_default();
                if target.starts_with('#') {
                    continue;
                }
                let file = target.strip_prefix("/ui/").unwrap_or(target);
                assert!(
                    ASSETS.iter().any(|a| a.path == file),
                    "index.html loads {target}, which is not embedded"
                );
            }
        }
    }

    #[test]
    fn entity_tags_follow_the_content() {
        assert_eq!(fnv1a(b""), 0xcbf2_9ce4_8422_2325);
        assert_ne!(fnv1a(b"a"), fnv1a(b"b"));
        assert_eq!(ETAGS.len(), ASSETS.len());
    }
}
