// Validate one glTF file with the Khronos glTF-Validator (npm package "gltf-validator") and print its JSON report.
// Usage: node gltf_validate.js VALIDATOR_MODULE_DIR FILE.gltf
const validator = require(process.argv[2]);
const fs = require("fs");
const path = require("path");
const file = process.argv[3];
validator
  .validateBytes(new Uint8Array(fs.readFileSync(file)), {
    uri: file,
    externalResourceFunction: (uri) =>
      new Promise((resolve, reject) =>
        fs.readFile(path.resolve(path.dirname(file), decodeURIComponent(uri)), (err, data) =>
          err ? reject(err.toString()) : resolve(new Uint8Array(data)),
        ),
      ),
  })
  .then((report) => console.log(JSON.stringify(report)))
  .catch((err) => {
    console.error(String(err));
    process.exit(1);
  });
