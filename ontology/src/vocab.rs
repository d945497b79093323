//! IRIs of the DyKnow, DyKnow-ROS and standard vocabularies used by the knowledge service.
//!
//! The names follow the seed's Appendix A (`dyknow`) and Ch. 5.3.1 (`dkros`).

macro_rules! terms {
    ($ns:literal; $($(#[$doc:meta])* $name:ident = $local:literal;)*) => {
        /// The namespace IRI.
        pub const NAMESPACE: &str = $ns;
        $(
            $(#[$doc])*
            pub const $name: oxrdf::NamedNodeRef<'static> =
                oxrdf::NamedNodeRef::new_unchecked(concat!($ns, $local));
        )*
        /// Every term above.
        pub const ALL: &[oxrdf::NamedNodeRef<'static>] = &[$($name),*];
    };
}

/// The DyKnow core ontology, `http://www.dyknow.eu/ontology/dyknow#` (seed, Appendix A).
pub mod dyknow {
    terms! { "http://www.dyknow.eu/ontology/dyknow#";
        /// `dyknow:Transformation`, a stream-generating function (seed Def. 17).
        TRANSFORMATION = "Transformation";
        /// `dyknow:Source`, a transformation without in ports.
        SOURCE = "Source";
        /// `dyknow:Sink`, a transformation without out ports.
        SINK = "Sink";
        /// `dyknow:ComputationUnit` (seed 4.59).
        COMPUTATION_UNIT = "ComputationUnit";
        /// `dyknow:Target` (seed Def. 19).
        TARGET = "Target";
        /// `dyknow:Channel`.
        CHANNEL = "Channel";
        /// `dyknow:Port`.
        PORT = "Port";
        /// `dyknow:InPort`.
        IN_PORT = "InPort";
        /// `dyknow:OutPort`.
        OUT_PORT = "OutPort";
        /// `dyknow:Tag`.
        TAG = "Tag";
        /// `dyknow:Parameter`.
        PARAMETER = "Parameter";
        /// `dyknow:Subscription`.
        SUBSCRIPTION = "Subscription";
        /// `dyknow:CostModel`.
        COST_MODEL = "CostModel";
        /// `dyknow:LabourCostModel`.
        LABOUR_COST_MODEL = "LabourCostModel";
        /// `dyknow:UpkeepCostModel`.
        UPKEEP_COST_MODEL = "UpkeepCostModel";
        /// `dyknow:ChangeSet`.
        CHANGE_SET = "ChangeSet";
        /// `dyknow:Environment`.
        ENVIRONMENT = "Environment";
        /// `dyknow:hasInPort`.
        HAS_IN_PORT = "hasInPort";
        /// `dyknow:hasOutPort`.
        HAS_OUT_PORT = "hasOutPort";
        /// `dyknow:isOutPort`, the inverse of `hasOutPort`.
        IS_OUT_PORT = "isOutPort";
        /// `dyknow:isInPort`, the inverse of `hasInPort`.
        IS_IN_PORT = "isInPort";
        /// `dyknow:hasName`.
        HAS_NAME = "hasName";
        /// `dyknow:hasPortName` (⊑ `hasName`).
        HAS_PORT_NAME = "hasPortName";
        /// `dyknow:hasChannelName` (⊑ `hasName`).
        HAS_CHANNEL_NAME = "hasChannelName";
        /// `dyknow:hasTag`.
        HAS_TAG = "hasTag";
        /// `dyknow:hasTagDescription`.
        HAS_TAG_DESCRIPTION = "hasTagDescription";
        /// `dyknow:hasValue`.
        HAS_VALUE = "hasValue";
        /// `dyknow:hasLabel`.
        HAS_LABEL = "hasLabel";
        /// `dyknow:hasCostModel`.
        HAS_COST_MODEL = "hasCostModel";
        /// `dyknow:hasChannel`.
        HAS_CHANNEL = "hasChannel";
        /// `dyknow:instanceOf`.
        INSTANCE_OF = "instanceOf";
        /// `dyknow:hasInstance`.
        HAS_INSTANCE = "hasInstance";
        /// `dyknow:hasSubscription`.
        HAS_SUBSCRIPTION = "hasSubscription";
        /// `dyknow:toCU`.
        TO_CU = "toCU";
        /// `dyknow:fromCU`.
        FROM_CU = "fromCU";
        /// `dyknow:toPort`.
        TO_PORT = "toPort";
        /// `dyknow:fromPort`.
        FROM_PORT = "fromPort";
        /// `dyknow:dependsOn` (seed 4.63).
        DEPENDS_ON = "dependsOn";
        /// `dyknow:similarTo`, this project's addition (symmetric, not transitive).
        SIMILAR_TO = "similarTo";
    }
}

/// The DyKnow-ROS extension, `http://www.dyknow.eu/ontology/dyknow-ros#` (seed, Ch. 5.3.1).
pub mod dkros {
    terms! { "http://www.dyknow.eu/ontology/dyknow-ros#";
        /// `dkros:ROSTransformation` (seed 5.3).
        ROS_TRANSFORMATION = "ROSTransformation";
        /// `dkros:ROSTarget`.
        ROS_TARGET = "ROSTarget";
        /// `dkros:Topic` (⊑ `dyknow:Channel`).
        TOPIC = "Topic";
        /// `dkros:Nodelet` (⊑ `dyknow:ComputationUnit`, seed 5.7).
        NODELET = "Nodelet";
        /// `dkros:hasPort` (seed 5.4, 5.5).
        HAS_PORT = "hasPort";
        /// `dkros:hasType`.
        HAS_TYPE = "hasType";
        /// `dkros:hasSource`.
        HAS_SOURCE = "hasSource";
        /// `dkros:hasParam`.
        HAS_PARAM = "hasParam";
        /// `dkros:hasExecutor`, this project's addition: the executor a transformation is
        /// pinned to (`executors.md`).
        HAS_EXECUTOR = "hasExecutor";
        /// `dkros:hasIndex`, the position of a port or tag in the posted spec, or of an action
        /// in its change set.
        HAS_INDEX = "hasIndex";
        /// `dkros:Publication`, the binding of a CU's out port to a channel.
        PUBLICATION = "Publication";
        /// `dkros:hasPublication`.
        HAS_PUBLICATION = "hasPublication";
        /// `dkros:publishesPort`.
        PUBLISHES_PORT = "publishesPort";
        /// `dkros:onChannel`.
        ON_CHANNEL = "onChannel";
        /// `dkros:isProtected`: change sets never destroy the CU.
        IS_PROTECTED = "isProtected";
        /// `dkros:historicalAverageLabour` (seed Eq. 5.8).
        HISTORICAL_AVERAGE_LABOUR = "historicalAverageLabour";
        /// `dkros:historicalAverageUpkeep` (seed Eq. 5.9).
        HISTORICAL_AVERAGE_UPKEEP = "historicalAverageUpkeep";
        /// `dkros:observationCount`.
        OBSERVATION_COUNT = "observationCount";
        /// `dkros:Action`, one action of a change set.
        ACTION = "Action";
        /// `dkros:hasAction`.
        HAS_ACTION = "hasAction";
        /// `dkros:actionKind` (`spawn`, `connect-in`, …).
        ACTION_KIND = "actionKind";
        /// `dkros:cuName`.
        CU_NAME = "cuName";
        /// `dkros:transformationLabel`.
        TRANSFORMATION_LABEL = "transformationLabel";
        /// `dkros:portName`.
        PORT_NAME = "portName";
        /// `dkros:channelName`.
        CHANNEL_NAME = "channelName";
        /// `dkros:atTime`, when a change set was made.
        AT_TIME = "atTime";
        /// `dkros:totalCost`, a change set's estimated cost.
        TOTAL_COST = "totalCost";
        /// `dkros:cause`, why a change set was made.
        CAUSE = "cause";
        /// `dkros:changeSetJson`, the whole change set as change set JSON.
        CHANGE_SET_JSON = "changeSetJson";
        /// `dkros:reservesName`: a name the life-cycle never hands out again, kept when the
        /// change sets that used it are pruned from the history.
        RESERVES_NAME = "reservesName";
    }
}

/// RDF.
pub mod rdf {
    terms! { "http://www.w3.org/1999/02/22-rdf-syntax-ns#";
        /// `rdf:type`.
        TYPE = "type";
    }
}

/// RDFS.
pub mod rdfs {
    terms! { "http://www.w3.org/2000/01/rdf-schema#";
        /// `rdfs:label`.
        LABEL = "label";
        /// `rdfs:subClassOf`.
        SUB_CLASS_OF = "subClassOf";
        /// `rdfs:comment`.
        COMMENT = "comment";
    }
}

/// OWL.
pub mod owl {
    terms! { "http://www.w3.org/2002/07/owl#";
        /// `owl:Ontology`.
        ONTOLOGY = "Ontology";
        /// `owl:equivalentClass`.
        EQUIVALENT_CLASS = "equivalentClass";
        /// `owl:equivalentProperty`.
        EQUIVALENT_PROPERTY = "equivalentProperty";
        /// `owl:Thing`.
        THING = "Thing";
        /// `owl:TransitiveProperty`.
        TRANSITIVE_PROPERTY = "TransitiveProperty";
    }
}

/// XSD.
pub mod xsd {
    terms! { "http://www.w3.org/2001/XMLSchema#";
        /// `xsd:string`.
        STRING = "string";
        /// `xsd:double`.
        DOUBLE = "double";
        /// `xsd:decimal`.
        DECIMAL = "decimal";
        /// `xsd:integer`.
        INTEGER = "integer";
        /// `xsd:float`.
        FLOAT = "float";
        /// `xsd:boolean`.
        BOOLEAN = "boolean";
        /// `xsd:nonNegativeInteger`.
        NON_NEGATIVE_INTEGER = "nonNegativeInteger";
        /// `xsd:dateTime`.
        DATE_TIME = "dateTime";
    }
}

/// The prefixes used when the service writes RDF or OWL, as `(prefix, namespace)`.
pub const PREFIXES: [(&str, &str); 7] = [
    ("dyknow", dyknow::NAMESPACE),
    ("dkros", dkros::NAMESPACE),
    ("rdf", rdf::NAMESPACE),
    ("rdfs", rdfs::NAMESPACE),
    ("owl", owl::NAMESPACE),
    ("xsd", xsd::NAMESPACE),
    ("dc", "http://purl.org/dc/terms/"),
];
