//! The nameplate of a machine (`identification` tables): the properties of OPC 40001-1's
//! `MachineIdentificationType` a plant may set for the gateway, a driveline or a mill.

/// One nameplate property: its key in the file and its browse name in OPC UA
/// (OPC 40001-1 `MachineIdentificationType`, OPC 10000-100 nameplate names).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum IdentificationField {
    /// `manufacturer`: `Manufacturer` (LocalizedText), e.g. `SMS group`.
    Manufacturer,
    /// `manufacturer_uri`: `ManufacturerUri` (String, a URI).
    ManufacturerUri,
    /// `model`: `Model` (LocalizedText), the manufacturer's model name.
    Model,
    /// `product_code`: `ProductCode` (String), the manufacturer's order code.
    ProductCode,
    /// `hardware_revision`: `HardwareRevision` (String).
    HardwareRevision,
    /// `serial_number`: `SerialNumber` (String), unique for the manufacturer.
    SerialNumber,
    /// `product_instance_uri`: `ProductInstanceUri` (String, a URI), globally unique.
    ProductInstanceUri,
    /// `year_of_construction`: `YearOfConstruction` (UInt16), 1800..=2100.
    YearOfConstruction,
    /// `asset_id`: `AssetId` (String), the plant's own id of the machine.
    AssetId,
    /// `location`: `Location` (String), where the machine stands in the plant.
    Location,
}

impl IdentificationField {
    /// Every property, in the order the OPC UA server and the web API list them.
    pub const ALL: [Self; 10] = [
        Self::Manufacturer,
        Self::ManufacturerUri,
        Self::Model,
        Self::ProductCode,
        Self::HardwareRevision,
        Self::SerialNumber,
        Self::ProductInstanceUri,
        Self::YearOfConstruction,
        Self::AssetId,
        Self::Location,
    ];

    /// Its key in an `identification` table (and in the web API).
    pub fn key(self) -> &'static str {
        match self {
            Self::Manufacturer => "manufacturer",
            Self::ManufacturerUri => "manufacturer_uri",
            Self::Model => "model",
            Self::ProductCode => "product_code",
            Self::HardwareRevision => "hardware_revision",
            Self::SerialNumber => "serial_number",
            Self::ProductInstanceUri => "product_instance_uri",
            Self::YearOfConstruction => "year_of_construction",
            Self::AssetId => "asset_id",
            Self::Location => "location",
        }
    }

    /// Its browse name in OPC UA (in the DI namespace, OPC 10000-100).
    pub fn browse_name(self) -> &'static str {
        match self {
            Self::Manufacturer => "Manufacturer",
            Self::ManufacturerUri => "ManufacturerUri",
            Self::Model => "Model",
            Self::ProductCode => "ProductCode",
            Self::HardwareRevision => "HardwareRevision",
            Self::SerialNumber => "SerialNumber",
            Self::ProductInstanceUri => "ProductInstanceUri",
            Self::YearOfConstruction => "YearOfConstruction",
            Self::AssetId => "AssetId",
            Self::Location => "Location",
        }
    }

    /// Whether its value must be a URI (`scheme:rest`).
    pub fn is_uri(self) -> bool {
        matches!(self, Self::ManufacturerUri | Self::ProductInstanceUri)
    }
}

/// A checked nameplate value.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum IdentificationValue {
    /// Text: 1..=255 characters, no control characters (a URI for the URI fields).
    Text(String),
    /// `year_of_construction`.
    Year(u16),
}

impl std::fmt::Display for IdentificationValue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Text(text) => f.write_str(text),
            Self::Year(year) => write!(f, "{year}"),
        }
    }
}

/// A machine's nameplate (`identification = { ... }`): the properties given, in the
/// order of [`IdentificationField::ALL`], each once; empty when the table is left out.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Identification {
    /// The properties set, in [`IdentificationField::ALL`]'s order.
    pub fields: Vec<(IdentificationField, IdentificationValue)>,
}

impl Identification {
    /// The value of `field`, when set.
    pub fn get(&self, field: IdentificationField) -> Option<&IdentificationValue> {
        self.fields
            .iter()
            .find_map(|(f, value)| (*f == field).then_some(value))
    }

    /// This nameplate with `field` set to `value` where it is not set (kept in order).
    pub fn or_default(mut self, field: IdentificationField, value: &str) -> Self {
        if self.get(field).is_none() {
            self.fields
                .push((field, IdentificationValue::Text(value.to_owned())));
            self.fields.sort_by_key(|(field, _)| *field);
        }
        self
    }
}
