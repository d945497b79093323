//! Content negotiation: `Accept` (with q-values and wildcards) and `Content-Type`.

use axum::http::{HeaderMap, header};

use crate::error::ApiError;

/// Picks the offer the client prefers. No `Accept` (or `*/*`) picks the first offer; an
/// `Accept` that excludes every offer is a 406.
pub fn negotiate<'a>(headers: &HeaderMap, offers: &[&'a str]) -> Result<&'a str, ApiError> {
    let Some(accept) = headers
        .get(header::ACCEPT)
        .and_then(|v| v.to_str().ok())
        .filter(|v| !v.trim().is_empty())
    else {
        return offers
            .first()
            .copied()
            .ok_or_else(|| ApiError::not_acceptable(offers));
    };
    let ranges: Vec<(String, f32)> = accept
        .split(',')
        .filter_map(|part| {
            let mut params = part.split(';');
            let range = params.next()?.trim().to_ascii_lowercase();
            if range.is_empty() {
                return None;
            }
            let mut q = 1.0f32;
            for p in params {
                if let Some(v) = p.trim().strip_prefix("q=") {
                    q = v.trim().parse().unwrap_or(0.0);
                }
            }
            Some((range, q))
        })
        .collect();
    let mut best: Option<(&str, f32)> = None;
    for offer in offers {
        let (otype, _) = offer.split_once('/').unwrap_or((offer, ""));
        // The most specific matching range decides the offer's quality.
        let mut quality: Option<(u8, f32)> = None;
        for (range, q) in &ranges {
            let specificity = if range == offer {
                3
            } else if range.strip_suffix("/*") == Some(otype) {
                2
            } else if range == "*/*" {
                1
            } else {
                continue;
            };
            if quality.is_none_or(|(s, _)| specificity > s) {
                quality = Some((specificity, *q));
            }
        }
        if let Some((_, q)) = quality
            && q > 0.0
            && best.is_none_or(|(_, bq)| q > bq)
        {
            best = Some((offer, q));
        }
    }
    best.map(|(o, _)| o)
        .ok_or_else(|| ApiError::not_acceptable(offers))
}

/// The media type of a message's body (a request's or an answer's), without parameters,
/// lower-cased.
pub fn content_type(headers: &HeaderMap) -> Option<String> {
    headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .map(|v| {
            v.split(';')
                .next()
                .unwrap_or("")
                .trim()
                .to_ascii_lowercase()
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::http::HeaderValue;

    fn pick(accept: Option<&str>, offers: &[&'static str]) -> Option<&'static str> {
        let mut h = HeaderMap::new();
        if let Some(a) = accept {
            h.insert(header::ACCEPT, HeaderValue::from_str(a).unwrap());
        }
        negotiate(&h, offers).ok()
    }

    #[test]
    fn negotiation_follows_rfc_9110() {
        let offers = ["application/json", "text/turtle"];
        assert_eq!(pick(None, &offers), Some("application/json"));
        assert_eq!(pick(Some("*/*"), &offers), Some("application/json"));
        assert_eq!(pick(Some("text/turtle"), &offers), Some("text/turtle"));
        assert_eq!(pick(Some("text/*"), &offers), Some("text/turtle"));
        assert_eq!(
            pick(Some("application/json;q=0.5, text/turtle"), &offers),
            Some("text/turtle")
        );
        assert_eq!(
            pick(Some("*/*, application/json;q=0"), &offers),
            Some("text/turtle")
        );
        assert_eq!(pick(Some("image/png"), &offers), None);
        assert_eq!(pick(Some("text/turtle;q=0"), &offers[1..]), None);
    }
}
