//! A flat OPC UA address space for the server at scale, shared by
//! `tests/opcua_delivery.rs` and `benches/opcua.rs` (included with `#[path]`):
//! `objects` drivelines `D<k>` of `variables` doubles `v<j>` each, node ids
//! `Millgate/Drivelines/D<k>/v<j>`.

use std::time::{Duration, SystemTime};

use millgate::outputs::opcua::model::{
    AddressSpaceSpec, ObjectKind, ObjectSpec, Snapshot, Value, VariableSpec, VariableType,
    VariableUpdate,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// `objects` drivelines of `variables` doubles each.
pub(crate) fn spec(objects: usize, variables: usize) -> AddressSpaceSpec {
    AddressSpaceSpec {
        name: "bench".into(),
        objects: (0..objects)
            .map(|k| ObjectSpec {
                name: format!("D{k}"),
                kind: ObjectKind::Driveline,
                parent: None,
                description: String::new(),
                variables: (0..variables)
                    .map(|j| VariableSpec {
                        key: format!("v{j}"),
                        description: String::new(),
                        unit: None,
                        datatype: VariableType::Double,
                        range: None,
                        states: Vec::new(),
                    })
                    .collect(),
                conditions: Vec::new(),
            })
            .collect(),
        machines: Vec::new(),
    }
}

/// Every value `value`, measured now.
pub(crate) fn snapshot(objects: usize, variables: usize, value: u64) -> Snapshot {
    let update = VariableUpdate::good(Value::Double(value as f64), Some(SystemTime::now()));
    Snapshot {
        objects: vec![vec![update; variables]; objects],
        machines: Vec::new(),
    }
}

/// Wait until the server answers a Hello.
pub(crate) async fn serving(address: std::net::SocketAddr, url: &str) {
    let mut body = Vec::new();
    for word in [0u32, 65_535, 65_535, 0, 0] {
        body.extend_from_slice(&word.to_le_bytes());
    }
    body.extend_from_slice(&(url.len() as u32).to_le_bytes());
    body.extend_from_slice(url.as_bytes());
    let mut hello = b"HELF".to_vec();
    hello.extend_from_slice(&(8 + body.len() as u32).to_le_bytes());
    hello.extend_from_slice(&body);
    let mut stream = tokio::net::TcpStream::connect(address).await.unwrap();
    stream.write_all(&hello).await.unwrap();
    let mut answer = [0u8; 4];
    tokio::time::timeout(Duration::from_secs(60), stream.read_exact(&mut answer))
        .await
        .expect("the server answers")
        .unwrap();
    assert_eq!(&answer, b"ACKF");
}
