// Validates a glTF file with the Khronos glTF validator (npm `gltf-validator`), as CI does
// (tests/exports_interop.rs). Prints the report's counts and messages as JSON; exits 1 on any
// error or warning. Usage: NODE_PATH=DIR/node_modules node scripts/validate-gltf.cjs FILE
const fs = require('fs');
const validator = require('gltf-validator');

const file = process.argv[2];
validator
  .validateBytes(new Uint8Array(fs.readFileSync(file)))
  .then((report) => {
    const issues = report.issues;
    console.log(JSON.stringify({
      errors: issues.numErrors,
      warnings: issues.numWarnings,
      messages: issues.messages.map((m) => `${m.code} ${m.message} ${m.pointer || ''}`),
    }));
    process.exit(issues.numErrors + issues.numWarnings > 0 ? 1 : 0);
  })
  .catch((e) => {
    console.error(`${file}: ${e}`);
    process.exit(2);
  });
