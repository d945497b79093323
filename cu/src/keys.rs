//! Where things live on Zenoh (`executors.md`, *Channels on Zenoh*): a channel `/ball/position`
//! is the key expression `<namespace>/channel/ball/position`; control keys live under the
//! hermetic prefix `<namespace>/@dyknow/...`, which no wildcard subscription on the namespace
//! matches (`docs/executors.md`).

use crate::error::KeyError;

/// The namespace of a DyKnow deployment: the first chunks of every key (`dyknow` by default).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Namespace(String);

impl Default for Namespace {
    fn default() -> Self {
        Self("dyknow".to_owned())
    }
}

impl std::fmt::Display for Namespace {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

/// Checks that `chunks` ('/'-separated) is a sequence of non-empty key-expression chunks
/// without wildcards or hermetic (`@`) chunks.
fn check_chunks(what: &'static str, chunks: &str) -> Result<(), KeyError> {
    if chunks.is_empty() {
        return Err(KeyError::Empty(what));
    }
    for chunk in chunks.split('/') {
        if chunk.is_empty() {
            return Err(KeyError::EmptyChunk {
                what,
                name: chunks.to_owned(),
            });
        }
        if let Some(c) = chunk.chars().find(|c| matches!(c, '*' | '$' | '?' | '#')) {
            return Err(KeyError::Forbidden {
                what,
                name: chunks.to_owned(),
                character: c,
            });
        }
        if chunk.starts_with('@') {
            return Err(KeyError::Hermetic {
                what,
                name: chunks.to_owned(),
            });
        }
    }
    Ok(())
}

impl Namespace {
    /// A namespace: one or more key-expression chunks (`dyknow`, `lab/robot1`).
    pub fn new(namespace: impl Into<String>) -> Result<Self, KeyError> {
        let namespace = namespace.into();
        check_chunks("namespace", &namespace)?;
        Ok(Self(namespace))
    }

    /// The namespace as a string.
    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// The key expression of a channel: `<namespace>/channel/<name without one leading '/'>`.
    pub fn channel(&self, channel: &str) -> Result<String, KeyError> {
        let chunks = channel.strip_prefix('/').unwrap_or(channel);
        check_chunks("channel name", chunks)?;
        Ok(format!("{}/channel/{chunks}", self.0))
    }

    /// The channel a key expression of [`Namespace::channel`] names, with the leading '/'
    /// given back if the name had one is unknowable; so this returns the chunks after
    /// `channel/`.
    pub fn channel_of<'k>(&self, key: &'k str) -> Option<&'k str> {
        key.strip_prefix(self.0.as_str())?.strip_prefix("/channel/")
    }

    /// The hermetic prefix of the control keys: `<namespace>/@dyknow`.
    pub fn control(&self) -> String {
        format!("{}/@dyknow", self.0)
    }

    /// An executor's liveliness token (present while the executor is).
    pub fn executor_token(&self, executor: &str) -> String {
        format!("{}/executor/{executor}", self.control())
    }

    /// The liveliness key expression matching every executor's token.
    pub fn executor_tokens(&self) -> String {
        format!("{}/executor/*", self.control())
    }

    /// The liveliness token of one instance of an executor, `<ns>/@dyknow/executor/<name>/<instance>`
    /// (an [`InstanceId`]): Zenoh announces a key once however many sessions hold it, so the
    /// name's own token cannot tell two executors of one name apart; these can.
    pub fn executor_instance(&self, executor: &str, instance: &InstanceId) -> String {
        format!("{}/executor/{executor}/{instance}", self.control())
    }

    /// The liveliness key expression matching the instance tokens of executor `executor`
    /// (`"*"`: of every executor).
    pub fn executor_instances(&self, executor: &str) -> String {
        format!("{}/executor/{executor}/*", self.control())
    }

    /// The executor's queryable for change sets (`apply`), its description (`info`) and
    /// implementation checks (`check`).
    pub fn executor_service(&self, executor: &str, service: &str) -> String {
        format!("{}/service/{executor}/{service}", self.control())
    }

    /// Where an executor publishes its events (crashes, measured costs).
    pub fn executor_events(&self, executor: &str) -> String {
        format!("{}/events/{executor}", self.control())
    }

    /// The key expression matching every executor's events.
    pub fn all_executor_events(&self) -> String {
        format!("{}/events/*", self.control())
    }

    /// A CU's liveliness token (present while the CU runs): `<namespace>/@dyknow/cu/*/<cu>`.
    ///
    /// The `*` chunk is deliberate. A Zenoh router forwarding a declaration to another router
    /// maps the declaration's non-wild prefix to a numeric id on that link and keeps the
    /// mapping, on both ends, for as long as the link lives. A key of its own per CU
    /// (`.../cu/<cu>`) therefore cost ~3 kB in the executor and the manager for every CU ever
    /// started (a crash storm starts thousands), and made each declaration slower as the
    /// mappings piled up; behind the `*` every CU shares one mapping (`cu/examples/zenoh_key_growth.rs`,
    /// docs/reliability.md, guarantee 3). The key still names exactly one CU: `*` matches one
    /// chunk, and CU names are single chunks.
    pub fn cu_token(&self, cu: &str) -> String {
        format!("{}/cu/*/{cu}", self.control())
    }

    /// The liveliness key expression matching every CU's token.
    pub fn cu_tokens(&self) -> String {
        format!("{}/cu/*/*", self.control())
    }

    /// A process CU's control queryable, which its executor queries:
    /// `<namespace>/@dyknow/cu-control/*/<cu>` (the `*` as in [`Namespace::cu_token`]).
    pub fn cu_control(&self, cu: &str) -> String {
        format!("{}/cu-control/*/{cu}", self.control())
    }
}

/// Checks that a name (an executor's, a CU's) is one key-expression chunk.
pub fn check_name(what: &'static str, name: &str) -> Result<(), KeyError> {
    check_chunks(what, name)?;
    if name.contains('/') {
        return Err(KeyError::Slash {
            what,
            name: name.to_owned(),
        });
    }
    Ok(())
}

/// One run of an executor (an instance of its name): when it started and on which Zenoh
/// session. Instances order as their starts do, the session id breaking ties; that is how two
/// executors of one name agree on the one that keeps the name, the one that started first.
/// In a key chunk and in JSON it reads `<start, ms since the Unix epoch, 13 digits>-<zid>`
/// (`1764377000123-8fa3c1`), so that its text orders as it does.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct InstanceId {
    /// When it started, in milliseconds since the Unix epoch.
    pub started_ms: u64,
    /// Its Zenoh session's id (hexadecimal).
    pub zid: String,
}

impl InstanceId {
    /// The instance of a session that starts now.
    pub fn now(zid: impl Into<String>) -> Self {
        Self {
            started_ms: u64::try_from(crate::now_ms()).unwrap_or(0),
            zid: zid.into(),
        }
    }
}

impl std::fmt::Display for InstanceId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:013}-{}", self.started_ms, self.zid)
    }
}

impl std::str::FromStr for InstanceId {
    type Err = KeyError;

    fn from_str(s: &str) -> Result<Self, KeyError> {
        let bad = || KeyError::Instance(s.to_owned());
        let (started, zid) = s.split_once('-').ok_or_else(bad)?;
        let hex = |c: char| c.is_ascii_hexdigit();
        if started.len() != 13 || zid.is_empty() || !zid.chars().all(hex) {
            return Err(bad());
        }
        Ok(Self {
            started_ms: started.parse().map_err(|_| bad())?,
            zid: zid.to_owned(),
        })
    }
}

impl serde::Serialize for InstanceId {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

impl<'de> serde::Deserialize<'de> for InstanceId {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let text = String::deserialize(deserializer)?;
        text.parse().map_err(serde::de::Error::custom)
    }
}

/// What an instance token's key ([`Namespace::executor_instance`]) says.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InstanceKey<'k> {
    /// The executor's name.
    pub name: &'k str,
    /// The instance.
    pub instance: InstanceId,
}

impl<'k> InstanceKey<'k> {
    /// The name and instance of an instance token's key; `None` for any other key.
    pub fn parse(key: &'k str) -> Option<Self> {
        let mut chunks = key.rsplitn(4, '/');
        let instance = chunks.next()?.parse().ok()?;
        let name = chunks.next()?;
        (chunks.next()? == "executor" && chunks.next()?.ends_with("@dyknow"))
            .then_some(Self { name, instance })
    }
}

/// Checks that a channel name maps to a key expression (`executors.md`).
pub fn check_channel(channel: &str) -> Result<(), KeyError> {
    check_chunks("channel name", channel.strip_prefix('/').unwrap_or(channel))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn channels_map_as_the_contract_says() {
        let ns = Namespace::default();
        assert_eq!(
            ns.channel("/ball/position").as_deref(),
            Ok("dyknow/channel/ball/position")
        );
        assert_eq!(ns.channel("101").as_deref(), Ok("dyknow/channel/101"));
        assert_eq!(ns.channel("ch-7").as_deref(), Ok("dyknow/channel/ch-7"));
        let lab = Namespace::new("lab/r1").expect("valid");
        assert_eq!(lab.channel("/a").as_deref(), Ok("lab/r1/channel/a"));
        assert_eq!(lab.channel_of("lab/r1/channel/a/b"), Some("a/b"));
        for bad in [
            "", "/", "a//b", "a/", "//a", "a*", "$x", "a?b", "#", "/@x", "a/@b",
        ] {
            assert!(ns.channel(bad).is_err(), "{bad:?} must be refused");
            assert!(check_channel(bad).is_err(), "{bad:?} must be refused");
        }
        assert!(Namespace::new("a/*").is_err());
        assert!(check_name("CU name", "cu-1").is_ok());
        assert!(check_name("CU name", "a/b").is_err());
    }

    #[test]
    fn instance_ids_order_by_start_then_session_as_their_text_does() {
        let id = |started_ms, zid: &str| InstanceId {
            started_ms,
            zid: zid.into(),
        };
        let ids = [
            id(999, "ff"),
            id(1_000, "0a"),
            id(1_000, "0b"),
            id(1_000, "a"),
        ];
        for pair in ids.windows(2) {
            assert!(pair[0] < pair[1], "{} before {}", pair[0], pair[1]);
            assert!(pair[0].to_string() < pair[1].to_string());
        }
        let later = &ids[1];
        assert_eq!(later.to_string(), "0000000001000-0a");
        assert_eq!(later.to_string().parse::<InstanceId>().as_ref(), Ok(later));
        for bad in [
            "",
            "1000-0a",
            "0000000001000",
            "0000000001000-",
            "0000000001000-xyz",
            "000000000100a-0a",
        ] {
            assert!(
                bad.parse::<InstanceId>().is_err(),
                "{bad:?} must be refused"
            );
        }
        let json = serde_json::to_string(later).unwrap();
        assert_eq!(json, "\"0000000001000-0a\"");
        assert_eq!(
            serde_json::from_str::<InstanceId>(&json).ok().as_ref(),
            Some(later)
        );
        let ns = Namespace::new("lab/r1").expect("valid");
        let key = ns.executor_instance("x", later);
        assert_eq!(
            InstanceKey::parse(&key),
            Some(InstanceKey {
                name: "x",
                instance: later.clone()
            })
        );
        assert_eq!(InstanceKey::parse(&ns.executor_token("x")), None);
        assert_eq!(InstanceKey::parse("lab/r1/@dyknow/service/x/info"), None);
        assert!(check_name("instance", &later.to_string()).is_ok());
    }

    #[test]
    fn control_keys_are_hermetic() {
        let ns = Namespace::default();
        assert_eq!(ns.executor_token("local"), "dyknow/@dyknow/executor/local");
        assert!(ns.cu_control("cu-1").starts_with("dyknow/@dyknow/"));
    }

    #[test]
    fn a_cu_key_names_one_cu_behind_a_shared_prefix() {
        use zenoh::key_expr::KeyExpr;
        let ns = Namespace::default();
        let key = |k: String| KeyExpr::try_from(k).unwrap();
        let (one, other) = (key(ns.cu_token("cu-1")), key(ns.cu_token("cu-12")));
        assert_eq!(one.as_str(), "dyknow/@dyknow/cu/*/cu-1");
        assert!(one.intersects(&one));
        assert!(
            !one.intersects(&other),
            "a CU's token must not match another CU's"
        );
        assert!(key(ns.cu_tokens()).includes(&one));
        assert!(!key(ns.cu_control("cu-1")).intersects(&key(ns.cu_control("cu-12"))));
        assert!(!key(ns.cu_control("cu-1")).intersects(&one));
        // The non-wild prefix, which Zenoh's routers map per link, is the same for every CU.
        assert_eq!(
            one.as_str().split("/*").next(),
            other.as_str().split("/*").next()
        );
    }
}
