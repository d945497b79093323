//! `JsonBody<T>`: the body of the JSON endpoints (`POST /cus`, `PUT /cus/{name}/config`,
//! `POST /perturbations`, `POST /statistics`), read as the contract says: 415 unless it is
//! declared as JSON, 413 over `--max-body`, 400 when it is not a JSON object of the expected
//! shape.

use axum::body::Bytes;
use axum::extract::{FromRequest, Request};
use axum::http::StatusCode;
use serde::de::DeserializeOwned;
use serde_json::{Value, json};

use crate::error::ApiError;
use crate::negotiate::content_type;

/// A JSON object body read as `T`. Unlike axum's `Json<T>`, a JSON array is refused even when
/// `T` is a struct (serde reads arrays as structs, field by field), a syntax error names its
/// line and column in `details` (as the RDF endpoints' do), and every rejection is the
/// contract's JSON error with the contract's status.
#[derive(Debug)]
pub struct JsonBody<T>(pub T);

/// Whether a media type declares JSON: `application/json` or `application/*+json`.
pub(crate) fn is_json(media: &str) -> bool {
    media == "application/json"
        || media
            .strip_prefix("application/")
            .is_some_and(|m| m.ends_with("+json"))
}

impl<S: Send + Sync, T: DeserializeOwned> FromRequest<S> for JsonBody<T> {
    type Rejection = ApiError;

    async fn from_request(request: Request, state: &S) -> Result<Self, ApiError> {
        JsonObject::from_request(request, state)
            .await?
            .read()
            .map(Self)
    }
}

/// A JSON object body, kept as its text too: a route that must look at a field before it
/// knows the shape (`POST /perturbations` answers an unknown `kind` with 422) still reads the
/// body with [`JsonObject::read`], so a field of the wrong type is named with its line and
/// column as [`JsonBody`] names it.
#[derive(Debug)]
pub struct JsonObject {
    /// The body as a JSON object.
    pub value: Value,
    text: Bytes,
}

impl JsonObject {
    /// The body read as `T`: 400 with the line and column of the first field that does not fit.
    pub fn read<T: DeserializeOwned>(&self) -> Result<T, ApiError> {
        // Read again from the text, not the value: a field of the wrong type or an unknown
        // one is then named with its line and column too.
        serde_json::from_slice(&self.text)
            .map_err(|e| at(&e, format!("the body does not fit: {e}")))
    }
}

impl<S: Send + Sync> FromRequest<S> for JsonObject {
    type Rejection = ApiError;

    async fn from_request(request: Request, state: &S) -> Result<Self, ApiError> {
        if !content_type(request.headers()).is_some_and(|m| is_json(&m)) {
            return Err(ApiError::new(
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
                "the body must be declared as JSON: use Content-Type application/json",
            ));
        }
        let text = Bytes::from_request(request, state).await.map_err(|e| {
            if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
                ApiError::new(
                    StatusCode::PAYLOAD_TOO_LARGE,
                    "the request body is larger than the server accepts",
                )
            } else {
                ApiError::new(e.status(), e.body_text())
            }
        })?;
        let value: Value = serde_json::from_slice(&text)
            .map_err(|e| at(&e, format!("the body is not JSON: {e}")))?;
        if !value.is_object() {
            return Err(ApiError::bad_request(
                "the body must be a JSON object (see /openapi.json)",
            ));
        }
        Ok(Self { value, text })
    }
}

/// A 400 whose `details` give where in the body `e` is (1-based, as the contract's syntax
/// errors are).
pub(crate) fn at(e: &serde_json::Error, message: String) -> ApiError {
    // serde_json counts columns from 1, but says 0 for an error before the first character
    // (an empty body): positions here are 1-based, in `details` and in the words alike.
    let (line, column) = (e.line().max(1), e.column().max(1));
    let said = format!("at line {} column {}", e.line(), e.column());
    let located = format!("at line {line} column {column}");
    ApiError::bad_request(message.replace(&said, &located)).with_details(vec![
        json!({"line": line, "column": column, "message": e.to_string().replace(&said, &located)}),
    ])
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::body::Body;
    use axum::http::StatusCode;

    #[derive(Debug, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Shape {
        name: String,
    }

    async fn read(content_type: Option<&str>, body: &str) -> Result<String, StatusCode> {
        let mut request = Request::builder().method("POST").uri("/");
        if let Some(t) = content_type {
            request = request.header("content-type", t);
        }
        let request = request.body(Body::from(body.to_owned())).unwrap();
        JsonBody::<Shape>::from_request(request, &())
            .await
            .map(|JsonBody(s)| s.name)
            .map_err(|e| e.status)
    }

    #[tokio::test]
    async fn bodies_read_as_the_contract_says() {
        let json = Some("application/json");
        assert_eq!(read(json, r#"{"name": "a"}"#).await, Ok("a".into()));
        assert_eq!(
            read(Some("application/json; charset=utf-8"), r#"{"name": "a"}"#).await,
            Ok("a".into())
        );
        assert_eq!(
            read(Some("application/merge-patch+json"), r#"{"name": "a"}"#).await,
            Ok("a".into())
        );
        // Not declared as JSON: 415, whatever the body.
        for t in [
            None,
            Some("text/plain"),
            Some("application/x-www-form-urlencoded"),
            Some("text/json+xml"),
        ] {
            assert_eq!(
                read(t, r#"{"name": "a"}"#).await,
                Err(StatusCode::UNSUPPORTED_MEDIA_TYPE)
            );
        }
        // Not JSON, not an object (an array would read as a struct), not the shape: 400.
        for body in [
            "{",
            r#"["a"]"#,
            "1",
            r#"{"name": 1}"#,
            r#"{"name": "a", "x": 1}"#,
            "{}",
        ] {
            assert_eq!(
                read(json, body).await,
                Err(StatusCode::BAD_REQUEST),
                "{body}"
            );
        }
    }

    #[tokio::test]
    async fn a_syntax_error_names_its_line_and_column() {
        let request = Request::builder()
            .method("POST")
            .uri("/")
            .header("content-type", "application/json")
            .body(Body::from("{\n  \"name\": ,\n}"))
            .unwrap();
        let e = JsonBody::<Shape>::from_request(request, &())
            .await
            .unwrap_err();
        assert_eq!(e.status, StatusCode::BAD_REQUEST);
        assert_eq!(e.details.len(), 1, "{e:?}");
        assert_eq!(
            (
                e.details[0]["line"].as_u64(),
                e.details[0]["column"].as_u64()
            ),
            (Some(2), Some(11))
        );
        assert!(e.message.contains("line 2 column 11"), "{}", e.message);
        // An empty body: the error is before the first character, at column 1.
        let request = Request::builder()
            .method("POST")
            .uri("/")
            .header("content-type", "application/json")
            .body(Body::empty())
            .unwrap();
        let e = JsonBody::<Shape>::from_request(request, &())
            .await
            .unwrap_err();
        assert_eq!(
            (
                e.details[0]["line"].as_u64(),
                e.details[0]["column"].as_u64()
            ),
            (Some(1), Some(1))
        );
        // And the words say the same (they said column 0).
        assert!(e.message.contains("line 1 column 1"), "{}", e.message);
        assert!(!e.message.contains("column 0"), "{}", e.message);
        // A field of the wrong type, or one the body may not have: where it is.
        for (body, line) in [
            ("{\n  \"name\": 7\n}", 2),
            ("{\"name\": \"a\",\n\n \"x\": 1}", 3),
        ] {
            let request = Request::builder()
                .method("POST")
                .uri("/")
                .header("content-type", "application/json")
                .body(Body::from(body))
                .unwrap();
            let e = JsonBody::<Shape>::from_request(request, &())
                .await
                .unwrap_err();
            assert_eq!(e.status, StatusCode::BAD_REQUEST);
            assert!(
                e.message.starts_with("the body does not fit: "),
                "{}",
                e.message
            );
            assert_eq!(e.details[0]["line"].as_u64(), Some(line), "{body}: {e:?}");
        }
    }
}
