// One node of a clustered MQTT broker for the Sparkplug failover test: aedes with its
// messages passed between nodes by mqemitter-redis and its state (retained messages,
// subscriptions, Wills, QoS 1 queues) kept by aedes-persistence-redis, both on one
// redis-server. Several processes of this script on one redis are one cluster: a
// message published on any node reaches the subscribers of every node, a retained
// message is kept for all, and the Wills of a node that died are sent by the others
// once its heartbeat is missed (3 heartbeat intervals, checked every 4).
//
// usage: node aedes_node.mjs MQTT_PORT REDIS_PORT NODE_ID [HEARTBEAT_MS]
// Listens on 127.0.0.1:MQTT_PORT; prints {"ready": true, ...} once it does.

import net from 'node:net'
import { Aedes } from 'aedes'
import mqemitterRedis from 'mqemitter-redis'
import persistenceRedis from 'aedes-persistence-redis'

const [mqttPort, redisPort, nodeId, heartbeatMs = '1000'] = process.argv.slice(2)
if (!mqttPort || !redisPort || !nodeId) {
  console.error('usage: node aedes_node.mjs MQTT_PORT REDIS_PORT NODE_ID [HEARTBEAT_MS]')
  process.exit(2)
}
// No ready check (INFO) and no CLIENT SETINFO on connecting: ioredis 5.8.2-5.x may
// send them after mqemitter-redis' SUBSCRIBE on the same connection, which redis
// refuses in subscriber mode; the error is thrown out of the emitter and the node
// dies at start-up (ioredis issue #2037, fixed by the handshake gate of 6.0.0; seen
// once in CI: "Connection in subscriber mode, only subscriber commands may be used").
const redis = {
  host: '127.0.0.1',
  port: Number(redisPort),
  enableReadyCheck: false,
  disableClientInfo: true
}
const persistence = persistenceRedis(redis)

// Worked around (aedes 1.2.0, aedes-packet 4.0.1): a node that sends the Will of a
// dead node's client keeps the dead node's brokerId in the packet but numbers it with
// its own brokerCounter, and a subscriber's QoS 1 deduplication (highest counter seen
// per brokerId) drops it when the dead node had numbered more messages to that
// subscriber: the Will is lost silently (seen in 2 of 2 runs of the Sparkplug test
// file in parallel; the host had QoS 1 DDATAs from the dead node). Numbered past any
// counter here, the Will passes once: a second node sending it too is a duplicate.
const streamWill = persistence.streamWill.bind(persistence)
persistence.streamWill = async function * (brokers) {
  for await (const will of streamWill(brokers)) {
    yield { ...will, brokerCounter: Number.MAX_SAFE_INTEGER }
  }
}

const broker = await Aedes.createBroker({
  id: nodeId,
  mq: mqemitterRedis(redis),
  persistence,
  heartbeatInterval: Number(heartbeatMs)
})
broker.on('clientError', (client, err) => {
  console.error(`${nodeId}: client ${client.id}: ${err.message}`)
})
const server = net.createServer(broker.handle)
server.listen(Number(mqttPort), '127.0.0.1', () => {
  console.log(JSON.stringify({ ready: true, node: nodeId, port: Number(mqttPort) }))
})
